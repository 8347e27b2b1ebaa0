"""Rerun for the app, off the control loop: the live stream of every session (:mod:`.live`), its
blueprint, the gRPC proxy and web viewer as child processes, and a Clean job's result logged by
the job itself."""
