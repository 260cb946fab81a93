"""Where the project's worker processes come from (the benchmark's pool, the batched env's
shards): one fork server per process. A small module of its own, so that a command can start the
server first thing, before importing the rest (:func:`start_worker_server`)."""

from __future__ import annotations

import contextlib
import multiprocessing
import signal
import threading
from collections.abc import Iterator


@contextlib.contextmanager
def sigint_deferred() -> Iterator[None]:
    """Hold Ctrl-C back while starting a worker (or the fork server that forks workers). Blocked,
    not ignored: the child is born with it blocked (its loop then ignores it, so only the parent
    handles Ctrl-C and stops the workers instead of every worker printing a traceback), and a
    Ctrl-C pressed meanwhile is not lost: it reaches the parent as soon as the worker has started."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    if not hasattr(signal, "pthread_sigmask"):  # no signal masks (Windows): ignore it meanwhile
        before = signal.signal(signal.SIGINT, signal.SIG_IGN)
        try:
            yield
        finally:
            signal.signal(signal.SIGINT, before)
        return
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)


WORKER_PRELOAD = ("smarts.worker_preload",)
"""What the fork server imports once for every worker (named, not imported, here): starting a
worker from a fresh interpreter costs 2-4 s of imports and set-up, paid again by each worker and
each replacement (see :mod:`smarts.worker_preload`)."""
TORCH_PRELOAD = ("torch",)
"""Imported by the fork server after :data:`WORKER_PRELOAD` (the policies' networks), unless the
server was started without it (:func:`start_worker_server`)."""


def worker_context():
    """Where workers come from: a fork server (a clean single-threaded process that has imported
    :data:`WORKER_PRELOAD`, forked per worker), or fresh interpreters (spawn) where there is no
    fork server. Never a fork of the caller, which may hold threads and open simulations."""
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("spawn")
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload([*WORKER_PRELOAD, *TORCH_PRELOAD])  # no effect once this process's server runs
    return ctx


_server_started = False


def start_worker_server(torch: bool = True, also: tuple[str, ...] = ()) -> None:
    """Start the fork server now (it imports :data:`WORKER_PRELOAD` while the caller goes on, say
    loading agents), so the workers later start at once. Nothing to do without a fork server.
    ``torch=False``: without :data:`TORCH_PRELOAD`, for a caller whose workers mostly run policies
    of code alone (the benchmark's reference agents): the server is ready 2 s sooner, and a worker
    whose policy is a network imports torch itself. ``also``: more modules for it to import (the
    benchmark's figure helpers come from it too)."""
    global _server_started
    context = worker_context()
    if context.get_start_method() == "forkserver":
        from multiprocessing import forkserver

        context.set_forkserver_preload([*WORKER_PRELOAD, *(TORCH_PRELOAD if torch else ()), *also])
        with sigint_deferred():  # the server, and so every worker it forks, is born with Ctrl-C blocked
            forkserver.ensure_running()
        _server_started = True


def worker_server_started() -> bool:
    """Whether this process started the fork server (:func:`start_worker_server`): then other
    helpers can come from it too, with the simulator's modules already imported."""
    return _server_started
