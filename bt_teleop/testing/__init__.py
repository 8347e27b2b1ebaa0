"""Harnesses shared by ``tests/`` and ``benchmarks/``, not used by the app: simulated tabs, the
app factory and headless Chromium (:mod:`.harness`), the Rerun web viewer's state read from a
page (:mod:`.viewer_probe`), and kill -9 fault injection into every writer (:mod:`.faults`)."""
