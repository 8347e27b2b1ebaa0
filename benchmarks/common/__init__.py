"""What the benchmark scripts share, the only modules they import from ``benchmarks/``.

* :mod:`.paths`: the repo root and the shared data folder beside it;
* :mod:`.timing`: medians of wall times;
* :mod:`.procfs`: a process's memory from ``/proc``;
* the soak's parts: :mod:`.soak_control` (control loops that only sleep), :mod:`.soak_late`
  (late ticks attributed), :mod:`.soak_memory` (memory by process kind), :mod:`.soak_tabs`
  (the tabs' websocket clients in a process of their own) and :mod:`.soak_drive` (a tab's
  driver doing what a person does).

A script run as a file (``python benchmarks/soak/bench_soak.py``) has only its own folder on
the import path, so those that import these put the repo root there first, in one line.
"""
