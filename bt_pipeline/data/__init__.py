"""Recordings and the pipeline's view of them: format v1 reader/writer/validator, typed records,
task planes and shapes, the demo view, and the synthetic demonstrators."""
