"""The ``forkserver`` that forks the app's children: the session children
(:mod:`bt_teleop.session.process`) and the library's reader.

It imports MuJoCo, mink and the session code once (the modules :func:`preload` named: the
session layer names its child's module); each child is forked from it (never from the app
itself: a plain ``fork`` of the many-threaded app is unsafe), so a child starts in well under a
second and shares those pages with the others.
"""

from __future__ import annotations

import multiprocessing
import multiprocessing.forkserver
import multiprocessing.spawn
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

__all__ = ["forkserver_context", "preload", "start_child", "start_forkserver"]

_context_lock = threading.Lock()
_starting = threading.local()
"""``_starting.session`` is True while this thread starts a session child."""
_stdlib_preparation_data: Callable[[str], dict[str, Any]] | None = None
_preload: list[str] = []
"""Modules the server imports when it starts (:func:`preload`)."""


def preload(module: str) -> None:
    """Have the server import `module` when it starts (no effect once it runs)."""
    with _context_lock:
        if module not in _preload:
            _preload.append(module)


def forkserver_context() -> Any:
    """The forkserver context, its server preloaded with MuJoCo, mink and the session code
    (:func:`preload`).

    A session child needs nothing of the app's main module, but ``multiprocessing`` makes every
    child import it again (the script's whole import graph: viser, ... for ~80 MiB of private
    memory per child in benchmarks/soak/bench_soak.py; CPython 3.11's forkserver cannot preload it,
    as it asks for a ``main_path`` key the preparation data never has). So the children started
    by :func:`start_child` get preparation data without the main module
    (:func:`_preparation_data`).
    """
    with _context_lock:
        if multiprocessing.spawn.get_preparation_data is not _preparation_data:
            global _stdlib_preparation_data
            _stdlib_preparation_data = multiprocessing.spawn.get_preparation_data
            multiprocessing.spawn.get_preparation_data = _preparation_data
        context = multiprocessing.get_context("forkserver")
        context.set_forkserver_preload(list(_preload))  # no effect once it runs
        return context


def start_forkserver() -> None:
    """Start the server that forks session children now (it then imports MuJoCo and mink in
    the background), not when the first session is made; a no-op once it runs."""
    forkserver_context()
    multiprocessing.forkserver.ensure_running()


def start_child(target: Callable[..., None], args: tuple[Any, ...], name: str) -> tuple[Any, Any]:
    """Start a session child running ``target(child_end, *args)``; (the app's end of its pipe,
    its process). Only the child holds the other end: its death is EOF on ours."""
    context = forkserver_context()
    conn, child_end = context.Pipe()
    process = context.Process(target=target, args=(child_end, *args), name=name, daemon=True)
    with _starting_session():
        process.start()
    child_end.close()
    return conn, process


@contextmanager
def _starting_session() -> Iterator[None]:
    """While in it, this thread's ``Process.start()`` starts a session child (no main module)."""
    _starting.session = True
    try:
        yield
    finally:
        _starting.session = False


def _preparation_data(name: str) -> dict[str, Any]:
    """multiprocessing's data for a new child; without the main module for a session child."""
    assert _stdlib_preparation_data is not None
    data = _stdlib_preparation_data(name)
    if getattr(_starting, "session", False):
        data.pop("init_main_from_path", None)
        data.pop("init_main_from_name", None)
    return data
