"""Reading, validating and writing checkpoint files safely, and the error every checkpoint loader raises.

Checkpoints are plain tensors and JSON-able metadata, read with ``torch.load(...,
weights_only=True)`` so nothing in a file executes code. Every format (PPO: ``agents.ppo``, SB3
exports: ``agents.sb3_policy``, the planners' networks: ``agents.planners.nets``) is a
:class:`CheckpointSchema`: every field with its type, size limits and finite bounds, validated
before any network is built, so a file can neither make the loader allocate what it asks for
(``hidden: [10**9]``) nor hand the simulator non-finite actions. A missing, corrupted, foreign or
inconsistent file is a :class:`CheckpointError` naming the file and the field
(``last.pt: action.space: required field missing``), whichever library wrote it.

Writes go through :func:`write_checkpoint`: the whole file is written to a temporary file beside the
target, then moved over it, so a failed write (a full disk) leaves the previous file intact and no
temporary file behind.
"""

from __future__ import annotations

import contextlib
import errno
import io
import os
import pickle
import types
import typing
import zipfile
from pathlib import Path
from typing import Annotated, Any, Mapping, TypeVar

import torch
from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationError

MAX_FILE_BYTES = 1 << 30
"""The most bytes a checkpoint archive may declare (its tensors are allocated as they are read)."""
MAX_PARAMETERS = 50_000_000
"""The most numbers (parameters and buffers) a network recorded in a checkpoint may hold."""
MAX_WIDTH = 8192
"""The widest layer (or input) a recorded network configuration may ask for."""
MAX_LAYERS = 16
"""The most layers (or rounds) a recorded network configuration may ask for."""
MAX_SHOWN = 8
"""Problems listed in one error; the rest are counted."""

M = TypeVar("M", bound=BaseModel)


class CheckpointError(ValueError):
    """A checkpoint file that cannot be used; the message names the file and what is wrong."""


class CheckpointWriteError(CheckpointError):
    """A checkpoint could not be written (a full disk, a folder that refuses writes); the message
    names the file, and the file's previous version is intact."""


# ------------------------------------------------------------------------------ the schema
class CheckpointSchema(BaseModel):
    """Base of every checkpoint model: unknown fields are errors, types are strict (``true`` is not
    a number) and tensors are checked as tensors."""

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True, arbitrary_types_allowed=True)


def _finite_tensors(tensors: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    for name, tensor in tensors.items():
        if tensor.is_floating_point() and not bool(torch.isfinite(tensor).all()):
            raise ValueError(f"tensor {name!r} holds NaN or infinite values; weights must be finite")
    return tensors


Finite = Annotated[float, Field(allow_inf_nan=False)]
"""A finite number (an integer is a valid one)."""
Width = Annotated[int, Field(ge=1, le=MAX_WIDTH)]
"""A layer width or input size within :data:`MAX_WIDTH`."""
Weights = Annotated[dict[str, torch.Tensor], AfterValidator(_finite_tensors)]
"""A module's state: named tensors, every floating one finite."""
Label = Annotated[str, Field(min_length=1, max_length=200)]
Metrics = dict[str, Any]
"""Recorded numbers and notes (not read back into a network)."""


def validate_checkpoint(model: type[M], blob: Any, path: str | Path) -> M:
    """``blob`` validated as ``model``; :class:`CheckpointError` naming ``path`` and each field at
    fault otherwise."""
    if not isinstance(blob, Mapping):
        raise CheckpointError(f"{path}: expected a mapping of checkpoint fields, found {type(blob).__name__}")
    try:
        return model.model_validate(dict(blob))
    except ValidationError as exc:
        problems = exc.errors()
        lines = [_describe(model, problem, path) for problem in problems[:MAX_SHOWN]]
        if len(problems) > MAX_SHOWN:
            lines.append(f"{path}: ... and {len(problems) - MAX_SHOWN} more problem(s)")
        raise CheckpointError("\n".join(lines)) from None


def _describe(model: type[BaseModel], problem: Mapping[str, Any], path: str | Path) -> str:
    """One pydantic problem as ``path: field.sub[2]['key']: message``."""
    loc = [part for part in problem["loc"] if not (isinstance(part, str) and "[" in part)]  # no validator tags
    where, annotation = "", model
    kind, message = problem["type"], problem["msg"]
    for i, part in enumerate(loc):
        fields = _model_fields(annotation)
        unknown = kind == "extra_forbidden" and i == len(loc) - 1  # a misspelt field is still a field
        if isinstance(part, str) and (part in fields or unknown):
            where += f".{part}" if where else part
            annotation = fields[part].annotation if part in fields else None
        else:  # a list index or a mapping key
            where += f"[{part!r}]" if isinstance(part, str) else f"[{part}]"
            annotation = _item_type(annotation)
    if kind == "missing":
        message = "required field missing"
    elif kind == "extra_forbidden":
        known = list(_model_fields(_parent(model, loc)))
        message = "unknown field" + (f" (known: {', '.join(known)})" if known else "")
    elif kind == "value_error":  # the model's own checks say everything themselves
        message = message.removeprefix("Value error, ")
    elif kind in ("model_type", "model_attributes_type", "dict_type"):  # never name a model class
        message = f"input should be a mapping, got {_short(problem.get('input'))}"
    elif kind == "is_instance_of":
        message = f"input should be a tensor, got {_short(problem.get('input'))}"
    else:
        message = f"{message[:1].lower()}{message[1:]}, got {_short(problem.get('input'))}"
    return f"{path}: {where or '<top>'}: {message}"


def _members(annotation: Any) -> list[Any]:
    """``annotation`` itself, or the members of a union / the type of an ``Annotated``."""
    if typing.get_origin(annotation) is typing.Annotated:
        return _members(typing.get_args(annotation)[0])
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        return [m for arg in typing.get_args(annotation) for m in _members(arg)]
    return [annotation]


def _model_fields(annotation: Any) -> dict[str, Any]:
    for member in _members(annotation):
        if isinstance(member, type) and issubclass(member, BaseModel):
            return dict(member.model_fields)
    return {}


def _item_type(annotation: Any) -> Any:
    """The type of a list's items or a mapping's values (None when unknown)."""
    for member in _members(annotation):
        args = typing.get_args(member)
        if args:
            return args[-1]
    return None


def _parent(model: Any, loc: list[Any]) -> Any:
    """The annotation that holds the last part of ``loc``."""
    annotation = model
    for part in loc[:-1]:
        fields = _model_fields(annotation)
        annotation = fields[part].annotation if isinstance(part, str) and part in fields else _item_type(annotation)
    return annotation


def _short(value: Any) -> str:
    if isinstance(value, torch.Tensor):
        return f"a tensor of shape {tuple(value.shape)}"
    if isinstance(value, Mapping):
        return f"a mapping of {len(value)} items"
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def mlp_size(sizes: list[int], out: int) -> int:
    """Parameters of fully connected layers ``sizes[0] -> ... -> sizes[-1] -> out`` (with biases)."""
    widths = [*sizes, out]
    return sum((a + 1) * b for a, b in zip(widths[:-1], widths[1:]))


def check_size(parameters: int, path: str | Path, what: str = "config") -> None:
    """Refuse a recorded network of more than :data:`MAX_PARAMETERS` numbers before it is built."""
    if parameters > MAX_PARAMETERS:
        raise CheckpointError(f"{path}: {what}: a network of {parameters:,} parameters; "
                              f"a checkpoint may hold at most {MAX_PARAMETERS:,}")  # fmt: skip


# ------------------------------------------------------------------------------ reading
def read_checkpoint(path: str | Path) -> Any:
    """The object stored in ``path``, read without executing code; clear errors otherwise. An
    archive that declares more than :data:`MAX_FILE_BYTES` is refused before anything is read."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: no such checkpoint file")
    _check_declared_size(path)
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # unpickling errors come in many types
        if isinstance(err, pickle.UnpicklingError) or "weights_only" in str(err).lower():
            why = "not a torch file, or one holding Python objects; only tensors and plain data are loaded"
        else:
            lines = str(err).strip().splitlines()
            why = f"{type(err).__name__}: {lines[0] if lines else ''}"
        raise CheckpointError(f"{path}: not a readable checkpoint ({why})") from None


def _check_declared_size(path: Path) -> None:
    """Torch files are zip archives, and ``torch.load`` allocates each record's declared size (it
    reads deflated records too, so a small file can declare gigabytes)."""
    try:
        with zipfile.ZipFile(path) as archive:
            declared = sum(info.file_size for info in archive.infolist())
    except (zipfile.BadZipFile, OSError, ValueError):
        return  # not an archive: torch.load says what it is
    if declared > MAX_FILE_BYTES:
        raise CheckpointError(f"{path}: the archive declares {declared:,} bytes of records; "
                              f"a checkpoint may hold at most {MAX_FILE_BYTES:,}")  # fmt: skip


def checkpoint_format(blob: Any) -> str | None:
    """The ``format`` tag a checkpoint records (None when it is not a tagged dict)."""
    return blob.get("format") if isinstance(blob, dict) else None


# ------------------------------------------------------------------------------ writing
def write_checkpoint(blob: Any, path: str | Path) -> Path:
    """Write ``blob`` (``weights_only`` loadable) to ``path`` atomically and durably; a failure
    (a full disk) is a :class:`CheckpointWriteError` and leaves ``path`` as it was."""
    buffer = io.BytesIO()
    torch.save(blob, buffer)
    return write_file_atomically(Path(path), buffer.getbuffer(), "checkpoint")


def write_file_atomically(path: Path, data: bytes | memoryview, what: str = "file") -> Path:
    """``data`` to ``path`` through a temporary file beside it, flushed to disk, then moved over
    ``path``: readers (and a run killed meanwhile) see the old file or the new one. On failure the
    temporary file is removed and :class:`CheckpointWriteError` names ``path`` and why."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view) :]
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, path)
    except OSError as err:
        _remove(tmp)
        kept = "its previous version is intact" if path.exists() else "nothing was written"
        raise CheckpointWriteError(f"{path}: could not write the {what} ({_reason(err)}); {kept}") from None
    except BaseException:
        _remove(tmp)
        raise
    return path


def _remove(path: Path) -> None:
    with contextlib.suppress(OSError):
        path.unlink(missing_ok=True)


def _reason(err: OSError) -> str:
    if err.errno in (errno.ENOSPC, errno.EDQUOT):
        return "no space left on the device"
    if err.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
        return "the folder refuses writes"
    return err.strerror or str(err)
