"""What the fork server of :mod:`smarts.worker_processes` loads once, so that every worker forked
from it starts warm: the modules the benchmark's units and the batched env's shards run and
numba's typing tables (filled by the first compiled call of a process, 0.2-0.4 s, however small
the kernel). Importing this module does that work; nothing else imports it. (The policies'
torch, 1.5-2 s of imports, is preloaded beside it unless the caller says its workers mostly do
without: :data:`~smarts.worker_processes.TORCH_PRELOAD`.)"""

import smarts.benchmark.batched  # noqa: F401
import smarts.benchmark.runner  # noqa: F401
import smarts.env.batched.driving  # noqa: F401
import smarts.traffic.builtin.provider  # noqa: F401 - imported by a simulation's first built-in traffic
from smarts.compiled import njit


@njit
def _first_compiled_call(x: int) -> int:
    return x + 1


_first_compiled_call(1)
