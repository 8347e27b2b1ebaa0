"""Harnesses shared by the tests and the benchmarks: fuzzing (:mod:`.fuzz`), operator sets
(:mod:`.operator_sets`) and free sockets (:mod:`.sockets`). Nothing in the pipeline imports them.
(Kill -9 fault injection covers the app's recorder too, so it lives in
:mod:`bt_teleop.testing.faults`: bt_pipeline never imports bt_teleop.)"""
