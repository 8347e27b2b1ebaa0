"""bt_teleop: the teleoperation web app (viser) on a simulated FR3 (MuJoCo + mink).

Its public API is ``bt teleop`` and what that command calls: :func:`bt_teleop.app.serve` (and
:func:`~bt_teleop.app.start_app`, non-blocking) with :class:`~bt_teleop.app_options.AppOptions`,
and the scripted operator :func:`bt_teleop.session.script.run_script`. One subpackage per
concern, lower layers first (each imports only those above it in this list; docs/architecture.md):

* ``proc/``: child-process plumbing (forkserver, die with the parent, priorities, C heap).
* ``sim/``: the task scene, the workspace and the IK.
* ``takes/``: a take and its file (recorder, take checks, naming, escaping).
* ``session/``: one session's control loop, in the app's process or a child of its own.
* ``rerun/``: live Rerun streaming, off the control loop.
* ``clean/``: the Clean button's job.
* ``library/``: a task's takes as the page lists them, and replaying one.
* ``ui/``: one browser tab (controller, panels, 3-D view).
* ``app.py``, ``app_options.py``: the viser server and its settings.
* ``testing/``: harnesses for the tests and benchmarks (the app never imports them).
"""
