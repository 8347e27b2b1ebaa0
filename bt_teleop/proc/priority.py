"""CPU priorities of the app's threads and children: background work lower, control loops
higher (or real-time).

::

    lower_priority(CLEAN_NICE)         first thing in a clean job's or the reader's process
    lower_thread_priority(CLEAN_NICE)  the app's library-loading thread
    raise_priority(boost)              a session's control loop thread (nice -boost, if allowed)
    use_realtime(priority)             a session's control loop thread under SCHED_RR
    command_priority(loop_priority)    the SCHED_RR priority of a session child's command thread

On Linux a nice value belongs to a thread, and threads started afterwards inherit it.
"""

from __future__ import annotations

import logging
import os
import threading

__all__ = [
    "CLEAN_NICE",
    "command_priority",
    "lower_priority",
    "lower_thread_priority",
    "raise_priority",
    "use_realtime",
]

LOGGER = logging.getLogger("bt.teleop")
CLEAN_NICE = 10
"""How much lower than the app a clean job's process runs (``nice``): training is batch work,
and on a busy machine the sessions' control loops must get the CPU first."""


def lower_priority(increment: int = CLEAN_NICE) -> None:
    """Lower the CPU priority by `increment` (``os.nice``; nothing where absent).

    On Linux ``os.nice`` changes the calling thread's nice value only, and threads started
    afterwards inherit it: call it first in a child process (a clean job, the reader), before
    any thread starts, and the whole process runs lower.
    """
    if hasattr(os, "nice"):
        try:
            os.nice(increment)
        except OSError:  # not permitted here: run at the app's priority
            LOGGER.debug("could not lower the clean job's priority", exc_info=True)


def lower_thread_priority(increment: int = CLEAN_NICE) -> None:
    """Lower the calling thread's CPU priority by `increment` (Linux keeps a nice value per
    thread; elsewhere nothing): the app's library loads run below the sessions' control loops."""
    if hasattr(os, "setpriority") and hasattr(threading, "get_native_id"):
        tid = threading.get_native_id()
        try:
            os.setpriority(os.PRIO_PROCESS, tid, os.getpriority(os.PRIO_PROCESS, tid) + increment)
        except OSError:
            LOGGER.debug("could not lower the thread's priority", exc_info=True)


def raise_priority(boost: int) -> int | None:
    """Lower this thread's nice value by `boost` if permitted; its nice value (None: unknown)."""
    if not hasattr(os, "getpriority"):
        return None
    tid = threading.get_native_id()  # Linux: a thread's own nice value
    nice = os.getpriority(os.PRIO_PROCESS, tid)
    if boost > 0:
        try:
            os.setpriority(os.PRIO_PROCESS, tid, max(-20, nice - boost))
        except PermissionError:
            LOGGER.info("control loop priority not raised: not permitted (ulimit -e)")
    return os.getpriority(os.PRIO_PROCESS, tid)


def use_realtime(priority: int, *, quiet: bool = False) -> bool:
    """Run this thread under ``SCHED_RR`` at `priority` (1..99; 0: keep its policy) if
    permitted; whether it now runs under a real-time policy (Linux). `quiet`: a refusal is
    not logged (a session child's command thread: its loop, asking next, says it once).

    A real-time thread runs before every normal one whenever it is runnable, so the machine's
    other work cannot keep it waiting for a CPU (what nice values only make less likely). The
    kernel still keeps 5 % of each second for normal threads (``sched_rt_runtime_us``), and the
    loop sleeps between ticks, so a session takes only the CPU its ticks need. Needs root,
    CAP_SYS_NICE or a ``ulimit -r`` of at least `priority`; else the policy stays (logged).
    """
    if not hasattr(os, "sched_setscheduler"):
        return False
    if priority > 0:
        try:  # pid 0: this thread (Linux)
            os.sched_setscheduler(0, os.SCHED_RR, os.sched_param(priority))
        except OSError as exc:
            if not quiet:
                LOGGER.info(
                    "control loop not made real-time (SCHED_RR %d): %s; allow it with an "
                    "rtprio limit (ulimit -r, /etc/security/limits.conf) or CAP_SYS_NICE, or "
                    "pass --realtime-priority 0",
                    priority,
                    exc,
                )
    return os.sched_getscheduler(0) in (os.SCHED_RR, os.SCHED_FIFO)


def command_priority(loop_priority: int) -> int:
    """The ``SCHED_RR`` priority of the thread serving a session's requests (0: normal policy).

    One step below its control loop's (at least 1): real-time, so no normal thread holds the
    GIL the loop needs, and below every session's loop, so the work it does (a take's save)
    never makes another session's loop wait behind it for ``SCHED_RR``'s 0.1 s quantum.
    """
    return max(1, loop_priority - 1) if loop_priority > 0 else 0
