"""Child-process plumbing of the app: the forkserver that forks the session and reader children,
what every child does for itself (die with its parent, send errors that unpickle), CPU
priorities and real-time scheduling, and the C heap (glibc malloc, HDF5's free lists).

Nothing here knows a session, a take or a tab; every other layer may use it."""
