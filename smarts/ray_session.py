"""Optional Ray connection for scale-out: benchmark episodes as Ray tasks, training collectors as
Ray actors. ``ray`` is imported here only, and only when an address is given, so runs without
``--ray-address`` never need it installed."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

LOCAL = "local"
LOOPBACK = "127.0.0.1"
"""Address a private (``local``) Ray instance listens on: reachable from this machine only."""


def import_ray():
    """The ``ray`` module, or an error that says how to install it."""
    try:
        import ray
    except ImportError as err:
        raise ValueError(f"--ray-address needs Ray ({err}); install it with: pip install 'smarts[ray]'") from None
    return ray


@contextlib.contextmanager
def ray_session(address: str, num_cpus: int = 2) -> Iterator[object]:
    """Connect to Ray at ``address`` for the block and yield the ``ray`` module.

    ``local`` starts a private Ray instance on this machine with ``num_cpus`` CPUs, listening on
    127.0.0.1 only (no dashboard), so nothing outside the machine can reach it; ``auto`` joins
    the cluster running here (``ray start --head``); ``HOST:PORT`` (or ``ray://HOST:PORT``) joins
    that cluster. A connection made here is closed at the end (a local instance is stopped); one
    that already existed is left open for its owner.
    """
    if not address or not isinstance(address, str):
        raise ValueError(f"ray address: expected auto, local or HOST:PORT, got {address!r}")
    ray = import_ray()
    connected_here = not ray.is_initialized()
    if connected_here:
        if address == LOCAL:
            with _loopback_node():
                ray.init(address="local", num_cpus=num_cpus, include_dashboard=False, log_to_driver=False,
                         configure_logging=False, _node_ip_address=LOOPBACK)  # fmt: skip
        else:
            ray.init(address=address, log_to_driver=False, configure_logging=False)
    try:
        yield ray
    finally:
        if connected_here:
            ray.shutdown()


@contextlib.contextmanager
def _loopback_node() -> Iterator[None]:
    """Let ``ray.init(_node_ip_address="127.0.0.1")`` keep the loopback address.

    On Linux, Ray replaces a loopback node address with the machine's network address (so that
    other machines could join), and its servers then listen on that interface. Ray keeps loopback
    where clusters are disabled (its Windows/macOS default, ``ENABLE_RAY_CLUSTER``), so that switch
    is turned off while a private instance starts. Were the switch ever to move, the instance still
    starts; ``tests/test_ray.py`` checks the address it listens on.
    """
    try:
        from ray._private import ray_constants
    except ImportError:
        yield
        return
    if not hasattr(ray_constants, "ENABLE_RAY_CLUSTER"):
        yield
        return
    before = ray_constants.ENABLE_RAY_CLUSTER
    ray_constants.ENABLE_RAY_CLUSTER = False
    try:
        yield
    finally:
        ray_constants.ENABLE_RAY_CLUSTER = before
