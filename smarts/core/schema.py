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
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ConfigDict, ValidationError

M = TypeVar("M", bound=BaseModel)


class Schema(BaseModel):
    """Base of every config model: unknown keys are errors (a typo never leaves a default in
    place), types are strict (``true`` is not a number, ``"3"`` is not an integer; an integer is
    a valid float) and a validated config is immutable."""

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True, validate_default=True)


def validate(model: type[M], data: Any, source: str, error: type[Exception] = ValueError) -> M:
    """``model`` validated from ``data``; problems raise ``error`` naming ``source`` and fields."""
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise error(f"{source}: expected a mapping at the top level, got {type(data).__name__}")
    try:
        return model.model_validate(dict(data))
    except ValidationError as exc:
        raise error("\n".join(describe(model, problem, source) for problem in exc.errors())) from None


def load_yaml(path: str | os.PathLike, what: str, error: type[Exception] = ValueError) -> Any:
    """The parsed YAML of ``path``; unreadable files and bad YAML raise ``error`` naming the file."""
    source = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise error(f"{source}: cannot read {what}: {exc.strerror or exc}") from None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise error(f"{source}: invalid YAML: {exc}") from None


def describe(model: type[BaseModel], problem: Mapping[str, Any], source: str) -> str:
    """One pydantic problem as ``source: a.b[2].c: message``."""
    loc = [part for part in problem["loc"] if not _is_validator_tag(part)]
    where = _dotted(loc) or "<top>"
    kind = problem["type"]
    if kind == "extra_forbidden":
        known = sorted(_fields_at(model, loc[:-1]))
        guess = difflib.get_close_matches(str(loc[-1]), known, n=1)
        hint = f"; did you mean {guess[0]!r}?" if guess else ""
        return f"{source}: {where}: unknown field{hint} (known: {', '.join(known)})"
    if kind == "missing":
        return f"{source}: {where}: required field missing"
    message = problem["msg"]
    if message.startswith("Value error, "):
        message = message[len("Value error, ") :]
    elif message.startswith("Assertion failed, "):
        message = message[len("Assertion failed, ") :]
    else:
        message = message[:1].lower() + message[1:]
    return f"{source}: {where}: {message}, got {problem.get('input')!r}"


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


def _fields_at(model: Any, loc: list[Any]) -> list[str]:
    """Field names of the model reached by following ``loc`` from ``model``."""
    current: Any = model
    for part in loc:
        if isinstance(part, int):
            current = _item_type(current)
            continue
        fields = getattr(current, "model_fields", None)
        if not fields or part not in fields:
            current = _item_type(current) if not fields else None
            if current is None or not hasattr(current, "model_fields") or part not in current.model_fields:
                return []
            fields = current.model_fields
        current = _model_in(fields[part].annotation)
    return list(getattr(current, "model_fields", {}) or {})


def _item_type(annotation: Any) -> Any:
    for arg in typing.get_args(annotation) or ():
        found = _model_in(arg)
        if found is not None:
            return found
    return _model_in(annotation)


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
