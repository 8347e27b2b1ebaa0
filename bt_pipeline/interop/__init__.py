"""Interop at the edges: export to LeRobot and robomimic, import their files (docs/interop.md)."""
