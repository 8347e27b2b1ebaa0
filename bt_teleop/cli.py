"""``bt teleop``: the app's command of the ``bt`` CLI.

bt_teleop registers it under the ``bt.commands`` entry-point group (pyproject.toml), and the CLI in
bt_pipeline loads every command of that group, so bt_pipeline never imports bt_teleop. The app is
imported inside the function, only when the command runs: ``bt --help`` stays fast.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Literal


def teleop(
    host: str = "127.0.0.1",
    port: int = 8080,
    robot: Literal["light", "menagerie"] = "light",
    recordings: Path = Path("recordings"),
    rerun: Literal["serve", "save", "off"] = "serve",
    max_sessions: int = 8,
    idle_timeout_s: float = 600.0,
    operator_token: str | None = None,
    script: Path | None = None,
    session_processes: bool = True,
    listed_demos: int = 50,
    realtime_priority: int = 10,
) -> None:
    """Open the teleoperation web app: drag a target, a simulated FR3 follows; record demos.

    Args:
        host: Interface to bind. 127.0.0.1 (this machine only) unless you mean to expose it,
            e.g. 0.0.0.0 for every interface.
        port: Port of the web app (the next free one if busy; the real URL is printed).
        robot: "light" (bundled FR3 model, no download) or "menagerie" (MuJoCo Menagerie's FR3
            with meshes; downloaded once, or read from $MENAGERIE_ROOT).
        recordings: Root folder of recordings; demos go to <recordings>/<task>/.
        rerun: "serve" streams to Rerun's web viewer on localhost, "save" writes .rrd files next
            to the recordings, "off" disables Rerun.
        max_sessions: Most browser tabs at once; more get a "full, try later" message.
        idle_timeout_s: A tab that sends nothing (no drag, click, typing or camera move) for
            this many seconds is closed to free its place, unless it is recording a take
            ("inf": never).
        operator_token: A secret (at least 8 characters); a tab that types it in the Recordings
            panel may exclude or restore anyone's demo. Without it, a tab moderates only its own
            demos. $BT_OPERATOR_TOKEN is used when the flag is not given.
        script: Run a scripted operator (JSON) without a browser: record, save, print the path.
        session_processes: Run each tab's simulation (control loop, IK, recorder) in a child
            process of its own, so the loops keep time beside the web server;
            --no-session-processes runs them in the app's process (one interpreter).
        listed_demos: The newest takes of a task each tab's Demo and Replay pickers offer,
            besides the table's best demos (the table's counts cover every take).
        realtime_priority: When 1..99, each tab's control loop (the thread serving it one
            step below) runs under the real-time scheduling policy SCHED_RR at this priority,
            so the machine's other work cannot delay its ticks. Tried by default; needs root,
            CAP_SYS_NICE or ulimit -r (else it is logged and left off). 0: off.
    """
    if script is not None:
        from bt_teleop.session.script import run_script

        print(run_script(script, recordings))
        return
    from bt_teleop.app import AppOptions, serve
    from bt_teleop.session.config import SessionConfig

    serve(
        AppOptions(
            host=host,
            port=port,
            robot=robot,
            recordings=recordings,
            rerun=rerun,
            max_sessions=max_sessions,
            idle_timeout_s=idle_timeout_s,
            operator_token=operator_token or os.environ.get("BT_OPERATOR_TOKEN") or None,
            session_processes=session_processes,
            listed_demos=listed_demos,
            session=SessionConfig(realtime_priority=realtime_priority),
        )
    )
