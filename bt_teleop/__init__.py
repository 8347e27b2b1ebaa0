"""bt_teleop: the teleoperation app's simulation core (MuJoCo + mink), and later its web UI.

One concept per module:

* :mod:`bt_teleop.scene`: compose a task scene (``scenes/<task>.xml``), an FR3 (our light
  model or MuJoCo Menagerie's) and a tool into a :class:`~bt_teleop.scene.SceneModel`.
* :mod:`bt_teleop.workspace`: the workspace box, the task-plane projection, target slewing.
* :mod:`bt_teleop.ik`: mink differential IK from an end-effector target to joint commands.
* :mod:`bt_teleop.recorder`: demo samples to a format-v1 file per demo.
* :mod:`bt_teleop.naming`: safe file names from a demonstrator's name.
* :mod:`bt_teleop.session`: one session's fixed-rate loop (target -> IK -> actuators -> physics
  -> recorder), in real time in a thread or stepped synchronously.
* :mod:`bt_teleop.script`: the scripted operator (JSON waypoints -> a recorded demo).
"""
