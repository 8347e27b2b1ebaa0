"""What every child process of the app does for itself: die with its parent, and send back
errors that unpickle.

::

    libc()                       the C library, loaded once (prctl below; the reader names itself)
    die_with_parent()            in a forked child (session, reader): SIGTERM when the
                                 forkserver, its parent, dies (it exits with the app)
    die_with_parent_hook()       a Popen ``preexec_fn`` (Rerun's proxy and web viewer): SIGTERM
                                 when the thread that started the child ends
    portable_error(exc)          an error ready to go through a pipe (a bug's traceback as a note)

Linux only (``PR_SET_PDEATHSIG``); elsewhere the first two do nothing and the hook is None.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import os
import pickle
import signal
import sys
import traceback
from collections.abc import Callable

from bt_pipeline.exceptions import BtError

__all__ = ["die_with_parent", "die_with_parent_hook", "libc", "portable_error"]

_PR_SET_PDEATHSIG = 1  # linux/prctl.h


@functools.cache
def libc() -> ctypes.CDLL:
    """The C library, loaded once (``find_library`` runs ``ldconfig`` on every call)."""
    return ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)


def die_with_parent() -> None:
    """Get SIGTERM when the forkserver (our parent; it exits with the app) dies (Linux)."""
    if not sys.platform.startswith("linux"):
        return
    parent = os.getppid()
    libc().prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
    if os.getppid() != parent:  # it died before prctl
        raise SystemExit(0)


def die_with_parent_hook() -> Callable[[], None] | None:
    """A ``preexec_fn`` that makes the child get SIGTERM when the spawning thread ends (Linux;
    None elsewhere). libc is loaded here, in the parent: the hook itself only calls prctl."""
    if not sys.platform.startswith("linux"):
        return None
    c_library = libc()
    parent = os.getpid()

    def hook() -> None:
        c_library.prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
        if os.getppid() != parent:  # the parent died before prctl: nobody will stop us
            os.kill(os.getpid(), signal.SIGTERM)

    return hook


def portable_error(exc: BaseException) -> BaseException:
    """`exc` ready to send: a bug's error (not a BtError) gets the child's traceback as a note;
    an error that does not survive pickling is replaced by a BtError with its text."""
    if not isinstance(exc, BtError):
        exc.add_note("in the session process:\n" + "".join(traceback.format_exception(exc)))
    try:
        pickle.loads(pickle.dumps(exc))
    except Exception:
        return BtError(f"{type(exc).__name__}: {exc}")
    return exc
