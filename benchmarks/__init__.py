"""bt's benchmarks: scripts by the question each answers (``quality/``, ``speed/``, ``scale/``,
``evaluation/``, ``teleop/``, ``soak/``, ``faults/``) and the helpers they share
(:mod:`benchmarks.common`). Not part of the installed package; see benchmarks/README.md."""
