"""Kernel records (``smarts.records``): fields found by name, the same arrays, and numba's
cache surviving a record class that disappeared."""

import os
import pickle
import sys
import types

import numba
import pytest
from numba.core.caching import IndexDataCacheFile

from smarts.core.sim_records import Lanes, freeze, lanes_of
from smarts.maps import load_map
from smarts.records import declare
from smarts.scenario import builtin_map_path


@numba.njit(cache=True)
def _lane_sums(frozen):  # pragma: no cover - compiled
    return frozen.length.sum(), frozen.width.sum(), frozen.succ_offsets[-1]


@numba.njit(cache=True)
def _widen(frozen, by):  # pragma: no cover - compiled
    frozen.width[0] += by


def test_a_frozen_record_reads_each_field_by_its_name_and_holds_the_same_arrays():
    rm = load_map(builtin_map_path("straight_3lane"))
    fields = lanes_of(rm)
    # built with the keywords in another order: the names decide, not the positions
    shuffled = Lanes(**dict(reversed(list(fields._asdict().items()))))
    for record in (freeze(fields), freeze(shuffled)):
        length, width, succ = _lane_sums(record)
        assert length == rm.lane_length.sum() and width == rm.lane_width.sum() and succ == rm.succ_offsets[-1]
    width = rm.lane_width.copy()
    _widen(freeze(lanes_of(rm)), 1.0)  # a kernel writing through a record writes the map's array
    assert rm.lane_width[0] == width[0] + 1.0
    rm.lane_width[0] = width[0]


def test_only_named_tuple_classes_become_records():
    with pytest.raises(TypeError, match="NamedTuple"):
        declare(dict)


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


_KERNEL = """
import numba
import dep
from smarts.records import cache_depends_on


@numba.njit(cache=True)
@cache_depends_on(dep)
def twice(x):
    return dep.scale(x) * 2
"""


def _run_kernel(folder, cache_dir) -> str:
    """A fresh interpreter imports the kernel from ``folder`` and calls it (numba's cache in ``cache_dir``)."""
    import os
    import subprocess

    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache_dir), "PYTHONPATH": os.pathsep.join([str(folder), *sys.path])}
    code = "import kern; print(kern.twice(1.0), sum(kern.twice.stats.cache_hits.values()))"
    return subprocess.run(
        [sys.executable, "-c", code], env=env, check=True, capture_output=True, text=True
    ).stdout.split()


def test_a_kernel_that_names_its_dependencies_recompiles_when_one_of_them_changes(tmp_path):
    """numba checks a cached function against its own file only: an edit of a module whose
    compiled function it calls must still reach it (``cache_depends_on``)."""
    folder, cache = tmp_path / "src", tmp_path / "cache"
    folder.mkdir()
    (folder / "kern.py").write_text(_KERNEL)
    dep = folder / "dep.py"
    dep.write_text("import numba\n\n\n@numba.njit(cache=True)\ndef scale(x):\n    return x * 3\n")
    assert _run_kernel(folder, cache)[0] == "6.0"
    assert _run_kernel(folder, cache) == ["6.0", "1"]  # from the cache
    dep.write_text("import numba\n\n\n@numba.njit(cache=True)\ndef scale(x):\n    return x * 50\n")
    os.utime(dep, (dep.stat().st_atime, dep.stat().st_mtime + 5))
    assert _run_kernel(folder, cache)[0] == "100.0"  # the edit is seen, not the cached old code


MAX_KERNEL_PARAMETERS = 12


def _compiled_functions(root):
    """(file, name, parameter count) of every ``numba.njit`` function under ``root``."""
    import ast
    from pathlib import Path

    for path in sorted(Path(root).rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef) and any("njit" in ast.unparse(d) for d in node.decorator_list):
                a = node.args
                yield path, node.name, len(a.posonlyargs) + len(a.args) + len(a.kwonlyargs) + bool(a.vararg)


def test_no_compiled_function_takes_more_than_a_dozen_parameters():
    """Kernels take records: numba binds by position, so a long list of same-typed arrays lets
    two swapped arguments pass silently."""
    from pathlib import Path

    import smarts

    found = list(_compiled_functions(Path(smarts.__file__).parent))
    assert len(found) > 100  # the scan sees the kernels
    too_many = [f"{p.name}:{name} ({n})" for p, name, n in found if n > MAX_KERNEL_PARAMETERS]
    assert not too_many, f"compiled functions with more than {MAX_KERNEL_PARAMETERS} parameters: {too_many}"
