"""One schema mechanism for every YAML config: pydantic v2 models with strict, closed fields.

Each config (metric constants, benchmark suites, training runs, ...) is a :class:`Schema`
subclass. :func:`validate` turns pydantic's errors into the project's own error type with one
line per problem, each naming the file, the dotted field path and what was expected, and a
"did you mean" for a misspelt key. :func:`cli_options` lists a model's top-level fields with their
types and defaults, so a command line offers the same overrides as the YAML, and ``--help`` shows
the defaults the schema holds.
"""

from __future__ import annotations

import difflib
import os
import typing
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ConfigDict, ValidationError
from pydantic_core import InitErrorDetails, PydanticCustomError

M = TypeVar("M", bound=BaseModel)


class Schema(BaseModel):
    """Base of every config model: unknown keys are errors (a typo never leaves a default in
    place), types are strict (``true`` is not a number, ``"3"`` is not an integer; an integer is
    a valid float) and a validated config is immutable."""

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True, validate_default=True)


def validate(
    model: type[M],
    data: Any,
    source: str,
    error: type[Exception] = ValueError,
    context: dict[str, Any] | None = None,
) -> M:
    """``model`` validated from ``data``; problems raise ``error`` naming ``source`` and fields.
    ``context`` reaches the model's validators (what they cannot know themselves)."""
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise error(f"{source}: expected a mapping at the top level, got {type(data).__name__}")
    try:
        return model.model_validate(dict(data), context=context)
    except ValidationError as exc:
        raise error("\n".join(describe(model, problem, source) for problem in exc.errors())) from None


_SAFE_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
"""libyaml's parser where PyYAML has it (about 7x faster; the same safe constructors build the
values), else the pure-Python one."""


def parse_yaml(text: str) -> Any:
    """YAML text as plain data (``yaml.safe_load``'s result), parsed by libyaml when available."""
    return yaml.load(text, Loader=_SAFE_LOADER)  # noqa: S506 - a safe loader


def load_yaml(path: str | os.PathLike, what: str, error: type[Exception] = ValueError) -> Any:
    """The parsed YAML of ``path``; unreadable files and bad YAML raise ``error`` naming the file."""
    source = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise error(f"{source}: cannot read {what}: {exc.strerror or exc}") from None
    try:
        return parse_yaml(text)
    except yaml.YAMLError as exc:
        raise error(f"{source}: invalid YAML: {exc}") from None


def describe(model: type[BaseModel], problem: Mapping[str, Any], source: str) -> str:
    """One pydantic problem as ``source: a.b[2].c: message``."""
    where, message = locate(model, problem)
    return f"{source}: {where or '<top>'}: {message}"


def locate(model: type[BaseModel], problem: Mapping[str, Any]) -> tuple[str, str]:
    """One pydantic problem as (dotted field path, message); the path is ``""`` at the top level."""
    loc = [part for part in problem["loc"] if not _is_validator_tag(part)]
    where = _dotted(loc)
    kind = problem["type"]
    if kind == "extra_forbidden":
        known = sorted(_fields_at(model, loc[:-1]))
        guess = difflib.get_close_matches(str(loc[-1]), known, n=1)
        hint = f"; did you mean {guess[0]!r}?" if guess else ""
        return where, f"unknown field{hint} (known: {', '.join(known)})"
    if kind == "missing":
        return where, "required field missing"
    if kind == CHECK:
        return where, problem["msg"]
    if kind in ("model_type", "model_attributes_type", "dict_type"):  # never name a model class
        return where, f"input should be a valid dictionary, got {_short(problem.get('input'))}"
    message = problem["msg"]
    if message.startswith("Value error, "):
        message = message[len("Value error, ") :]
    elif message.startswith("Assertion failed, "):
        message = message[len("Assertion failed, ") :]
    else:
        message = message[:1].lower() + message[1:]
    return where, f"{message}, got {_short(problem.get('input'))}"


CHECK = "check"
"""Error type of the problems a model's own checks report (:func:`field_errors`); their message is
complete as written."""


def field_errors(model: type[BaseModel] | BaseModel, problems: list[tuple[Any, str]]) -> ValidationError:
    """A ``ValidationError`` to raise from a model validator, with one problem per (location,
    message): the location (a field name, or a tuple of names and list indices; ``()`` for the
    model itself) is relative to the model, and pydantic prefixes it with the model's own place in
    the file, so every problem names its field exactly."""
    title = model.__name__ if isinstance(model, type) else type(model).__name__
    details = [
        InitErrorDetails(
            type=PydanticCustomError(CHECK, "{message}", {"message": message}),
            loc=loc if isinstance(loc, tuple) else (loc,),
            input=None,
        )
        for loc, message in problems
    ]
    return ValidationError.from_exception_data(title, details)


def cli_options(model: type[BaseModel]) -> list[tuple[str, Any, str]]:
    """(field name, default, help text) of every top-level field, the help showing type and default."""
    options = []
    for name, info in model.model_fields.items():
        default = info.get_default(call_default_factory=True)
        if isinstance(default, BaseModel):
            default = default.model_dump()
        kind = _type_name(info.annotation)
        doc = (info.description or "").strip()
        options.append((name, default, f"{doc + ' ' if doc else ''}({kind}; default: {default!r})"))
    return options


# ----------------------------------------------------------------------------------- helpers
def _is_validator_tag(part: Any) -> bool:
    """Union members and function validators add their own names to a location; hide them."""
    return isinstance(part, str) and ("[" in part or part.startswith(("function-", "constrained-")))


def _dotted(loc: list[Any]) -> str:
    text = ""
    for part in loc:
        text += f"[{part}]" if isinstance(part, int) else (f".{part}" if text else str(part))
    return text


def _short(value: Any) -> str:
    """A value for a message: its repr, or what it is when that is long (a whole mapping)."""
    text = repr(value)
    if len(text) > 80 and isinstance(value, (Mapping, list, tuple)):
        return f"a {'mapping' if isinstance(value, Mapping) else 'list'} of {len(value)} items"
    return text


def _fields_at(model: Any, loc: list[Any]) -> list[str]:
    """Field names of the model reached by following ``loc`` (fields, list indices, mapping keys)
    from ``model``."""
    annotation: Any = model
    for part in loc:
        annotation = _step(annotation, part)
        if annotation is None:
            return []
    found = _model_in(annotation)
    return list(found.model_fields) if found is not None else []


def _step(annotation: Any, part: Any) -> Any:
    """The annotation one location part below ``annotation``: a model's field, a list's item or a
    mapping's value (through optional, union and annotated wrappers)."""
    for member in _members(annotation):
        if isinstance(member, type) and issubclass(member, BaseModel):
            if isinstance(part, str) and part in member.model_fields:
                return member.model_fields[part].annotation
            continue
        origin, args = typing.get_origin(member), typing.get_args(member)
        if origin is None or not args:
            continue
        if isinstance(origin, type) and issubclass(origin, Mapping):
            return args[-1]
        if isinstance(part, int) and origin in (list, tuple, set, frozenset, Sequence):
            return args[0]
    return None


def _members(annotation: Any) -> list[Any]:
    """``annotation`` itself, or the members of a union / the type of an ``Annotated``."""
    origin = typing.get_origin(annotation)
    if origin is typing.Annotated:
        return _members(typing.get_args(annotation)[0])
    if origin is typing.Union or type(annotation).__name__ == "UnionType":
        return [m for arg in typing.get_args(annotation) for m in _members(arg)]
    return [annotation]


def _model_in(annotation: Any) -> Any:
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    for arg in typing.get_args(annotation) or ():
        found = _model_in(arg)
        if found is not None:
            return found
    return None


def _type_name(annotation: Any) -> str:
    text = getattr(annotation, "__name__", None) if not typing.get_args(annotation) else None
    return text or str(annotation).replace("typing.", "")
