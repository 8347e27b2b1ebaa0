"""One teleoperation session: the control loop (:mod:`.control_loop`), its config, its recording
lifecycle, its tick timing, the scripted operator, and the session run in a child process of
its own (:mod:`.process` in the app, :mod:`.child` in the child, :mod:`.pipe` between them,
:mod:`.recovery` when the child is lost)."""
