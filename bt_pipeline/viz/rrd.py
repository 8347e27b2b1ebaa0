"""An atomic, deterministic .rrd writer shared by every bt recording (the per-demo palette and
names are in :mod:`bt_pipeline.viz.demo_style`)."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import rerun as rr
import rerun.blueprint as rrb

from bt_pipeline.data.atomic import remove_stale_temps, temp_name
from bt_pipeline.exceptions import ConfigError


def save_rrd(
    path: Path,
    *,
    app_id: str,
    recording_id: str,
    name: str,
    blueprint: rrb.Blueprint,
    log: Callable[[rr.RecordingStream], None],
    disabled_hint: str,
) -> Path:
    """Log into a new deterministic stream and save it to `path` (.rrd), atomically.

    The stream has no wall-clock ``log_time`` timeline. It is written to a temporary file beside
    `path`, closed (footer written), fsynced, then moved into place; on any failure the
    temporary file is removed and `path` is left as it was.

    Raises:
        ConfigError: Rerun is disabled (RERUN=off); the message ends with `disabled_hint`.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temps(path)
    tmp = temp_name(path)
    rec = rr.RecordingStream(app_id, recording_id=recording_id, send_properties=False)
    if not rec.is_enabled():
        raise ConfigError(f"Rerun logging is disabled (RERUN=off); unset RERUN or {disabled_hint}")
    try:
        try:
            rec.set_log_time_enabled(False)
            rec.save(tmp)
            rec.send_recording_name(name)
            rec.send_blueprint(blueprint, make_active=True, make_default=True)
            log(rec)
            rec.flush()
        finally:
            rec.disconnect()  # Closes the file sink and writes the footer.
        with open(tmp, "rb") as written:
            os.fsync(written.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path
