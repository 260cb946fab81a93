"""Every cached compiled kernel names the modules whose compiled functions it calls.

numba's on-disk cache of a kernel holds the code of everything it calls but is checked only
against the kernel's own file; a kernel calling a function of another module must say so with
``smarts.records.cache_depends_on``, or an edit of that module goes on running old code from
the cache (until the cache is cleared), which no test would notice."""

from __future__ import annotations

import importlib
import pkgutil
import sys
import types

from numba.core.registry import CPUDispatcher

import smarts

SKIPPED_PACKAGES = ("smarts.viz", "smarts.diagnostic")  # no kernels of their own; heavy imports


def _kernels() -> list[CPUDispatcher]:
    for info in pkgutil.walk_packages(smarts.__path__, "smarts."):
        if not info.name.startswith(SKIPPED_PACKAGES) and not info.name.endswith("__main__"):
            importlib.import_module(info.name)
    found = {}
    for name, module in list(sys.modules.items()):
        if name.startswith("smarts."):
            for value in vars(module).values():
                if isinstance(value, CPUDispatcher) and value.py_func.__module__.startswith("smarts."):
                    found[id(value)] = value
    return list(found.values())


def _called(kernel: CPUDispatcher) -> list[CPUDispatcher]:
    """The compiled functions a kernel's code names (globals, ``module.function``, closures)."""
    func = kernel.py_func
    names, codes = set(), [func.__code__]
    while codes:
        code = codes.pop()
        names |= set(code.co_names)
        codes += [c for c in code.co_consts if isinstance(c, types.CodeType)]
    out = []
    for name in names:
        value = func.__globals__.get(name)
        if isinstance(value, CPUDispatcher):
            out.append(value)
        elif isinstance(value, types.ModuleType):
            out += [a for a in (getattr(value, n, None) for n in names) if isinstance(a, CPUDispatcher)]
    for cell in func.__closure__ or ():
        if isinstance(cell.cell_contents, CPUDispatcher):
            out.append(cell.cell_contents)
    return out


def _reachable(kernel: CPUDispatcher) -> list[CPUDispatcher]:
    seen, todo = {}, [kernel]
    while todo:
        for callee in _called(todo.pop()):
            if id(callee) not in seen:
                seen[id(callee)] = callee
                todo.append(callee)
    return list(seen.values())


def test_every_cached_kernel_depends_on_the_files_of_what_it_calls():
    kernels = [k for k in _kernels() if type(k._cache).__name__ != "NullCache"]  # njit(cache=True)
    assert len(kernels) > 50  # the walk found the simulator's kernels
    missing = {}
    for kernel in kernels:
        own = kernel.py_func.__code__.co_filename
        needed = {c.py_func.__code__.co_filename for c in _reachable(kernel)} - {own}
        declared = set(getattr(kernel.py_func, "__cache_depends__", ()))
        if needed - declared:
            missing[f"{kernel.py_func.__module__}.{kernel.py_func.__name__}"] = sorted(needed - declared)
    assert not missing, f"kernels to mark with cache_depends_on (module: files it calls into): {missing}"
