"""``smarts.compiled.njit``: numba's on-disk cache of a kernel is stale when a module its module
imports changes (a callee's code, a constant read from another module), every cached kernel of
``smarts`` is declared that way, and a cache index naming a class that is gone reads as stale."""

from __future__ import annotations

import importlib
import os
import pickle
import pkgutil
import re
import subprocess
import sys
import types
from pathlib import Path

import numba
from numba.core.caching import IndexDataCacheFile
from numba.core.registry import CPUDispatcher

import smarts
from smarts.compiled import imported_files

SKIPPED_PACKAGES = ("smarts.viz", "smarts.diagnostic")  # no kernels of their own; heavy imports

_PACKAGE = {
    "__init__.py": "",
    "table.py": 'COLUMN = {"x": 0, "y": 1}\n',
    "columns.py": 'from pkg.table import COLUMN\n\nY = COLUMN["y"]\n',  # a constant derived in between
    "dep.py": "from smarts.compiled import njit\n\n\n@njit\ndef scale(x):\n    return x * 3\n",
    "kern.py": (
        "from smarts.compiled import njit\nfrom pkg import dep\nfrom pkg.columns import Y\n\n\n"
        "@njit(nogil=True)\ndef twice(row):\n    return dep.scale(row[Y]) * 2\n"
    ),
}


def _run(folder: Path, cache: Path) -> list[str]:
    """A fresh interpreter calls ``pkg.kern.twice`` (numba's cache in ``cache``): its value and cache hits."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache), "PYTHONPATH": os.pathsep.join([str(folder), *sys.path])}
    code = "import numpy as np, pkg.kern as k; print(k.twice(np.array([1.0, 10.0, 100.0])), sum(k.twice.stats.cache_hits.values()))"  # noqa: E501
    done = subprocess.run([sys.executable, "-c", code], env=env, check=True, capture_output=True, text=True)
    return done.stdout.split()


def _edit(path: Path, text: str) -> None:
    path.write_text(text)
    os.utime(path, (path.stat().st_atime, path.stat().st_mtime + 5))  # a coarse clock still sees it


def test_a_cached_kernel_recompiles_when_a_module_it_imports_changes(tmp_path):
    folder, cache = tmp_path / "src", tmp_path / "cache"
    (folder / "pkg").mkdir(parents=True)
    for name, text in _PACKAGE.items():
        (folder / "pkg" / name).write_text(text)
    assert _run(folder, cache)[0] == "60.0"
    assert _run(folder, cache) == ["60.0", "1"]  # from the cache
    _edit(folder / "pkg" / "dep.py", _PACKAGE["dep.py"].replace("x * 3", "x * 50"))
    assert _run(folder, cache) == ["1000.0", "0"]  # a callee's edit is seen, not the cached old code
    _edit(folder / "pkg" / "table.py", 'COLUMN = {"y": 0, "x": 1}\n')  # columns reordered, two imports away
    assert _run(folder, cache) == ["100.0", "0"]
    assert _run(folder, cache) == ["100.0", "1"]


def test_the_imports_followed_are_the_packages_own_directly_or_through_others(tmp_path):
    (tmp_path / "pkg").mkdir()
    for name, text in _PACKAGE.items():
        (tmp_path / "pkg" / name).write_text(text)
    (tmp_path / "pkg" / "sub").mkdir()
    (tmp_path / "pkg" / "sub" / "__init__.py").write_text("")
    (tmp_path / "pkg" / "sub" / "deep.py").write_text(
        "import numpy\nfrom . import near\nfrom ..table import (\n    COLUMN,\n)\n\n\ndef f():\n    import pkg.dep\n"
    )
    (tmp_path / "pkg" / "sub" / "near.py").write_text("")
    names = {
        Path(p).relative_to(tmp_path).as_posix() for p in imported_files(str(tmp_path / "pkg/kern.py"), "pkg.kern")
    }
    assert names == {"pkg/kern.py", "pkg/__init__.py", "pkg/dep.py", "pkg/columns.py", "pkg/table.py"}
    deep = imported_files(str(tmp_path / "pkg/sub/deep.py"), "pkg.sub.deep")
    assert {Path(p).relative_to(tmp_path).as_posix() for p in deep} == {
        "pkg/sub/deep.py", "pkg/sub/__init__.py", "pkg/sub/near.py", "pkg/table.py", "pkg/__init__.py", "pkg/dep.py"
    }  # fmt: skip


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


def test_every_kernel_of_smarts_is_cached_following_its_imports_which_hold_what_it_calls():
    kernels = _kernels()
    assert len(kernels) > 50  # the walk found the simulator's kernels
    plain = [k.py_func.__qualname__ for k in kernels if type(k._cache._impl._locator).__name__ != "_FollowingLocator"]
    assert not plain, f"kernels not declared with smarts.compiled.njit: {plain}"
    missing = {}
    for kernel in kernels:
        followed = {str(p) for p in imported_files(kernel.py_func.__code__.co_filename, kernel.py_func.__module__)}
        seen, todo = {}, [kernel]
        while todo:
            for callee in _called(todo.pop()):
                if id(callee) not in seen:
                    seen[id(callee)] = callee
                    todo.append(callee)
        needed = {str(Path(c.py_func.__code__.co_filename).resolve()) for c in seen.values()}
        if needed - followed:
            missing[kernel.py_func.__qualname__] = sorted(needed - followed)
    assert not missing, f"kernels calling compiled code their cache does not follow: {missing}"
    raw = [
        str(p)
        for p in Path(smarts.__file__).parent.rglob("*.py")
        if p.name != "compiled.py" and re.search(r"cache\s*=\s*True", p.read_text())
    ]
    assert not raw, f"numba.njit(cache=True) outside smarts.compiled (use its njit): {raw}"


def test_a_cache_index_naming_a_record_class_that_is_gone_reads_as_stale(tmp_path):
    module = types.ModuleType("gone_records")
    exec("from typing import NamedTuple\nclass Old(NamedTuple):\n    a: int\n", module.__dict__)
    sys.modules["gone_records"] = module
    try:
        index = IndexDataCacheFile(str(tmp_path), "kernel", ("stamp", 1))
        with open(index._index_path, "wb") as f:
            pickle.dump(numba.__version__, f)
            f.write(pickle.dumps((("stamp", 1), {(module.Old(1),): "kernel.1.nbc"})))
    finally:
        del sys.modules["gone_records"]
    assert index._load_index() == {}  # numba compiles again and overwrites it, rather than failing
