"""Kernel records (``smarts.records``): fields found by name, the same arrays, and kernels
taking records rather than long argument lists."""

import numba
import pytest

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
