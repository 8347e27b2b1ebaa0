"""What every ``bt`` command shares: argument annotations, the logger, PATH checks."""

from __future__ import annotations

import logging
from typing import Annotated

import tyro

from bt_pipeline.exceptions import ConfigError

Paths = Annotated[
    list[str], tyro.conf.arg(metavar="PATH", help_behavior_hint="(required, one or more)")
]
"""Recording files, directories or glob patterns."""
Required = tyro.conf.arg(help_behavior_hint="(required)")
"""Help hint of a required option (tyro would print "(default: )" for some)."""

log = logging.getLogger("bt")


def require_paths(paths: list[str]) -> None:
    """Refuse an empty PATH list with one line (tyro accepts zero positional PATHs)."""
    if not paths:
        raise ConfigError("give at least one PATH (a recording file, directory or glob pattern)")
