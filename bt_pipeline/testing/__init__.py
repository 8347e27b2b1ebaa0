"""Harnesses shared by the tests and the benchmarks: fuzzing (:mod:`.fuzz`) and kill -9 fault
injection (:mod:`.faults`). Nothing in the pipeline imports them."""
