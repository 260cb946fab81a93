"""Kernel records: named groups of arrays handed to compiled kernels instead of long argument lists.

Why: numba binds arguments by position, so a kernel with dozens of array parameters turns two
swapped arrays of the same type into a silent wrong answer. A record names each array where it is
built (keywords) and where it is read (``record.field``).

A record has two forms:

- its *fields*: a ``typing.NamedTuple`` class (as ``smarts.maps.projection.Grids``), built with
  keywords in Python. Inside compiled code a tuple is how a record travels between functions: a
  value, free to pass, whose arrays stay in registers.
- its *frozen* form: a numba structref holding the same arrays (not copies), made once by
  ``freeze`` and passed from Python into a kernel.

What a call from Python costs numba to type its arguments (numba 0.68, measured on these machines):
about 0.1 us per array, about 1 us per frozen record whatever its size, and about 0.25 us per
field of a NamedTuple plus about 1.5 us to build the tuple. So arrays built once (maps, route and
junction tables, missions, state kept between steps) go into frozen records, and what changes
every step (the live rows, this step's projections, the clock, per-call outputs) is passed as a
few plain arguments: a record of those would cost microseconds per call, as much as the work of a
kernel at one agent.

Inside a kernel, read the fields it uses once, at the top (``data = tables.data``): each read of
a frozen field is a load and a new reference (about 40 ns with its release), so reading a few
fields of a large record is cheap where taking all of them is not, and a loop that writes arrays
while reading fields through the record reloads them on every access (the compiler cannot tell
that the writes miss the record; about 1.5x the time of the same loop over plain arrays).
``view(record)`` takes every field at once, for a kernel that uses most of them. Functions called
many times per call get tuples, not the frozen record.

Declaring one::

    class LaneGraph(NamedTuple):
        lane_length: np.ndarray  # float64[lanes]
        ...

    declare(LaneGraph)

    @njit  # smarts.compiled.njit
    def freeze(fields):  # one per module that declares records (see ``freeze_fields``)
        return freeze_fields(fields)

Frozen records are one level of arrays and numbers where kernels read single fields (a field that
is itself a tuple is read whole). A frozen record holds the arrays it was made from: rebuild it
when one of them is replaced (not when its contents change).
"""

from __future__ import annotations

import numba
from numba.core import types
from numba.core.extending import overload
from numba.experimental import structref

__all__ = ["declare", "freeze_fields", "picklable_state", "view"]


class _RecordType(types.StructRef):
    """numba type of a frozen record; each declared record has its own subclass."""

    fields_class: type = tuple

    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(typ)) for name, typ in fields)


class _FrozenRecord(structref.StructRefProxy):
    """What a frozen record is in Python: an opaque handle for kernels (read the fields tuple)."""

    __slots__ = ()


def declare(fields_class: type) -> type:
    """Make ``fields_class`` (a ``typing.NamedTuple`` class at module level) a kernel record.

    Adds ``fields_class.Frozen``, numba's type class of its frozen form, found by numba's on-disk
    cache as ``<module>.<Name>.Frozen`` (the cache pickles types by reference, so it must be
    importable), and returns ``fields_class``."""
    if not (isinstance(fields_class, type) and issubclass(fields_class, tuple) and hasattr(fields_class, "_fields")):
        raise TypeError(f"declare: expected a NamedTuple class, got {fields_class!r}")
    frozen = type(
        "Frozen", (_RecordType,),
        {"__module__": fields_class.__module__, "__qualname__": f"{fields_class.__qualname__}.Frozen",
         "fields_class": fields_class},
    )  # fmt: skip
    structref.register(frozen)
    proxy = type(
        f"Frozen{fields_class.__name__}", (_FrozenRecord,),
        {"__module__": fields_class.__module__, "__slots__": ()},
    )  # fmt: skip
    structref.define_boxing(frozen, proxy)
    fields_class.Frozen = frozen
    return fields_class


def freeze_fields(fields):  # pragma: no cover - replaced in compiled code
    """Compiled code only: the frozen record of a declared fields tuple (same arrays, not copies).

    Call it from a ``smarts.compiled.njit`` function in the module that declares the record:
    numba keys its cache of that function by the tuple's field types but not its field names, and
    drops it when that module's file changes, so a renamed or reordered field can never meet a
    stale compiled copy."""
    raise TypeError("freeze_fields runs in compiled code; call the module's own freeze")


def view(record):  # pragma: no cover - replaced in compiled code
    """Compiled code only: a frozen record's fields tuple (read once, at the top of a kernel)."""
    raise TypeError("view runs in compiled code")


def _impl(param: str, body: str, **names) -> object:
    """A function ``impl(<param>)`` with ``body`` (generated: the field names, identifiers of a
    NamedTuple, are spelled out) and ``names`` as its globals."""
    scope: dict = dict(names)
    exec(f"def impl({param}):\n{body}", scope)
    return scope["impl"]


@overload(freeze_fields, prefer_literal=False)
def _freeze_fields(fields):
    cls = getattr(fields, "instance_class", None)
    frozen = getattr(cls, "Frozen", None) if isinstance(fields, types.BaseNamedTuple) else None
    if frozen is None:
        raise numba.core.errors.TypingError(f"freeze_fields: expected a declared record's fields, got {fields}")
    struct_type = frozen(list(zip(fields.fields, fields.types)))
    body = "".join(f"    st.{f} = fields.{f}\n" for f in fields.fields)
    return _impl(
        "fields", f"    st = new(struct_type)\n{body}    return st\n", new=structref.new, struct_type=struct_type
    )


@overload(view, prefer_literal=False)
def _view(record):
    cls = getattr(record, "fields_class", None) if isinstance(record, _RecordType) else None
    if cls is None:
        raise numba.core.errors.TypingError(f"view: expected a frozen record, got {record}")
    names = [name for name, _ in record.field_dict.items()]
    return _impl("record", f"    return cls({', '.join(f'{n}=record.{n}' for n in names)})\n", cls=cls)


def picklable_state(state: dict) -> dict:
    """An object's ``__dict__`` without the frozen records kept in it (numba objects, which do not
    pickle): for ``__getstate__`` of objects that travel to worker processes and make their
    records again there."""
    from numba.experimental.structref import StructRefProxy

    return {k: v for k, v in state.items() if not isinstance(v, StructRefProxy)}
