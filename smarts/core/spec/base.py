"""The base of the spec models and the value types their fields share.

A spec model is a :class:`smarts.core.schema.Schema` (closed, strict, frozen): the same class is
what a YAML section validates into and what every layer reads, so a field is declared, checked and
documented once. Built in code, a model is checked by the same rules as when read from a file; a
problem raises the project's error naming the field instead of pydantic's ``ValidationError``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Annotated, Any, TypeVar

from pydantic import AfterValidator, BeforeValidator, Field, ValidationError, model_validator

from smarts.core.errors import ScenarioError
from smarts.core.schema import Schema, locate

S = TypeVar("S", bound="Spec")

MAX_SPEED = 70.0
"""m/s (252 km/h): the most a start speed, a traffic depart speed or a vehicle type's max_speed
may be. No road vehicle the simulator models goes faster; a larger number is a unit mistake."""
MAX_TIME = 1e7
"""s: the latest a flow may begin or end and a trip depart (the longest episode at 1 s steps)."""


def plain(value: Any) -> Any:
    """Numpy scalars as the Python numbers they hold, inside mappings and lists too (values built in
    code may be either; the strict fields take only Python numbers)."""
    if type(value).__module__ == "numpy" and hasattr(value, "item") and getattr(value, "ndim", 0) == 0:
        return value.item()
    if isinstance(value, Mapping):
        return {k: plain(v) for k, v in value.items()}
    if isinstance(value, list):
        return [plain(v) for v in value]
    return value


class Spec(Schema):
    """Base of every spec model (see the module docstring)."""

    def __init__(self, *args: Any, **data: Any) -> None:
        if args:  # fields in declaration order, as in TripSpec("lead", route=[...])
            names = list(type(self).model_fields)
            if len(args) > len(names):
                raise TypeError(f"{type(self).__name__} takes at most {len(names)} positional arguments")
            for name, value in zip(names, args):
                if name in data:
                    raise TypeError(f"{type(self).__name__} got {name!r} twice")
                data[name] = value
        try:
            super().__init__(**data)
        except ValidationError as exc:
            raise type(self).code_error(exc) from None

    # Validation from data (``model_validate``, nested sections) goes straight to pydantic; only a
    # call in code goes through this ``__init__``.
    __init__.__pydantic_base_init__ = True  # type: ignore[attr-defined]

    @classmethod
    def code_error(cls, exc: ValidationError) -> Exception:
        """The error raised for a model built in code with invalid values."""
        lines = []
        for problem in exc.errors():
            where, message = locate(cls, problem)
            lines.append(f"{cls.__name__}: {where or '<top>'}: {message}")
        return ScenarioError("\n".join(lines))

    @model_validator(mode="before")
    @classmethod
    def _plain_numbers(cls, data: Any) -> Any:
        return plain(data) if isinstance(data, Mapping) else data


def replace(model: S, **changes: Any) -> S:
    """A copy of ``model`` with ``changes``, validated again (a spec stays valid; its private
    attributes, such as where a scenario was read from, are kept)."""
    unknown = sorted(set(changes) - set(type(model).model_fields))
    # only what was given: a default left out stays left out (checks such as "one goal kind" tell
    # a given field from a default)
    values = {name: getattr(model, name) for name in model.model_fields_set}
    if unknown:
        raise TypeError(f"{type(model).__name__} has no field {', '.join(unknown)}")
    new = type(model)(**{**values, **changes})
    if model.__pydantic_private__:
        for name, value in model.__pydantic_private__.items():
            setattr(new, name, value)
    return new


def _non_blank(value: str) -> str:
    if not value.strip():
        raise ValueError("expected a non-empty string")
    return value


def _list(value: Any) -> Any:
    """A tuple given in code is checked as the list a file gives."""
    return list(value) if isinstance(value, tuple) else value


def _tuple(value: Any) -> Any:
    """Held as a tuple, which keeps a frozen model hashable."""
    return tuple(value) if isinstance(value, list) else value


Text = Annotated[str, AfterValidator(_non_blank)]
"""A non-empty string (an id, a road)."""
Number = Annotated[float, Field(allow_inf_nan=False)]
Positive = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegative = Annotated[float, Field(ge=0, allow_inf_nan=False)]
Speed = Annotated[float, Field(ge=0, le=MAX_SPEED, allow_inf_nan=False)]
"""m/s, from 0 to ``MAX_SPEED``."""
Time = Annotated[float, Field(ge=0, le=MAX_TIME, allow_inf_nan=False)]
"""s from the start of the episode, up to ``MAX_TIME``."""
Index = Annotated[int, Field(ge=0)]
AsList = BeforeValidator(_list)
AsTuple = AfterValidator(_tuple)
"""With ``AsList``: a list field (checked, and named in messages, as a list) held as a tuple."""
Point = Annotated[list[Number], Field(min_length=2, max_length=2), AsList, AsTuple]
"""[x, y] in metres (held as a tuple)."""


def given(model: Schema, *names: str) -> list[str]:
    """Which of ``names`` were given (explicitly, null included) rather than left to their default."""
    return [name for name in names if name in model.model_fields_set]
