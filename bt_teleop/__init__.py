"""bt_teleop: the teleoperation web app (viser) on a simulated FR3 (MuJoCo + mink).

One concept per module:

* :mod:`bt_teleop.scene`: compose a task scene (``scenes/<task>.xml``), an FR3 (our light
  model or MuJoCo Menagerie's) and a tool into a :class:`~bt_teleop.scene.SceneModel`.
* :mod:`bt_teleop.workspace`: the workspace box, the task-plane projection, target slewing.
* :mod:`bt_teleop.ik`: mink differential IK from an end-effector target to joint commands.
* :mod:`bt_teleop.recorder`: demo samples to a format-v1 file per demo.
* :mod:`bt_teleop.naming`: safe file names from a demonstrator's name.
* :mod:`bt_teleop.session`: one session's fixed-rate loop (target -> IK -> actuators -> physics
  -> recorder), in real time in a thread or stepped synchronously.
* :mod:`bt_teleop.session_process`: a tab's session in a child process of its own (one GIL per
  control loop), behind the part of the session's API the app uses.
* :mod:`bt_teleop.session_child`: that child's side: the session, served over a pipe.
* :mod:`bt_teleop.tick_stats`: the app's sessions time their ticks (gaps, stalls, priority).
* :mod:`bt_teleop.late_ticks`: why a tick was late (run-queue wait, collections, requests,
  the tick's phases), kept for every tick later than ``SessionConfig.late_tick_s``.
* :mod:`bt_teleop.session_config`: a session's rates and policies, and its status snapshot.
* :mod:`bt_teleop.session_recording`: a session's recording lifecycle (start, samples, save,
  a closed tab's demo flagged incomplete).
* :mod:`bt_teleop.script`: the scripted operator (JSON waypoints -> a recorded demo).
* :mod:`bt_teleop.app`: the viser server: one session per browser tab, start/stop, Ctrl-C.
* :mod:`bt_teleop.ui`: one tab's controller (:class:`~bt_teleop.ui.ClientUI`): its worker
  thread, commands and polling, tying the panels, the 3-D view and the session together.
* :mod:`bt_teleop.ui_panels`: one tab's GUI panels (task, θ/ρ, record, recordings, clean,
  replay), their callbacks and the status text.
* :mod:`bt_teleop.tab_scene`: one tab's 3-D view (robot, gizmo, target marker, guide, trail,
  replayed paths).
* :mod:`bt_teleop.ui_context`: what every tab shares (:class:`~bt_teleop.ui_context.UiContext`,
  :class:`~bt_teleop.ui_context.TaskVersions`).
* :mod:`bt_teleop.viewer`: drawing the MuJoCo model, trails and paths into a tab's own scene.
* :mod:`bt_teleop.replay`: playing raw or cleaned demos on the robot through IK.
* :mod:`bt_teleop.cleaning`: the Clean job (the cleaner in a background process).
* :mod:`bt_teleop.rerun_live`: live Rerun streaming off the control loop.
* :mod:`bt_teleop.testing`: the test harness shared by ``tests/`` and ``benchmarks/`` (simulated
  tabs, app factory, headless Chromium).
"""
