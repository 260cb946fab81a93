"""Checkpoint files that passed every check before: what they say about driving, without torch.

Loading a checkpoint imports torch (1.5-2.5 s) and reads and validates the whole file
(:mod:`agents.loader`). A process that only plans with a policy, as the benchmark's does (its
action space, controller, observation interface and batching decide which episodes share a
simulation), need not pay that when the same bytes passed the same checks before. After a
successful load, :func:`load_checkpoint_policy` remembers the policy's settings under the file's
content hash and a hash of the checking code (the loaders' sources and the torch version) in the
cache folder (``$SMARTS_CACHE_DIR/checked-checkpoints``); a later load of those bytes gives a
:class:`CheckedPolicy`, which answers those settings at once and loads the network (checked again,
as always) the first time anything else is asked of it: acting, checking an observation space.

A file that changed, a newer loader or torch, or an entry that does not read back are misses: the
file is loaded and checked in full, and a refused file is never remembered. Entries are a few
hundred bytes; one unused for :data:`KEEP_DAYS` is removed when another is written.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import time
from importlib import metadata
from pathlib import Path
from typing import Any

SETTINGS = ("action_space", "controller", "interface", "lane_relative", "comms", "batching")
"""The attributes a checked policy answers without loading (plain data, as the loaded policy has them)."""
ENTRY_VERSION = 1
KEEP_DAYS = 30
_CHECKING_CODE = ("checked.py", "checkpoint.py", "loader.py", "ppo.py", "sb3_policy.py")
_code_version: str | None = None


class CheckedPolicy:
    """A checkpoint's policy known to load: :data:`SETTINGS` and ``source`` at once; anything
    else the loaded policy has (``act``, ``act_episodes``, ``check_space``, ...) loads it first."""

    def __init__(self, path: Path, settings: dict[str, Any], names: list[str]):
        self.__dict__.update(settings)
        self.source = str(path)
        self._names = frozenset(names)
        self._policy: Any = None

    def __getattr__(self, name: str) -> Any:  # only for what the instance itself lacks
        if name.startswith("_") or name not in self.__dict__.get("_names", ()):
            raise AttributeError(name)
        value = getattr(self.loaded(), name)
        if callable(value):  # a bound method: kept, so the next call (every step) finds it directly
            self.__dict__[name] = value
        return value

    def loaded(self) -> Any:
        """The policy itself (the file read and checked now, the first time)."""
        if self._policy is None:
            from agents.loader import load_policy_file

            self._policy = load_policy_file(self.source)
        return self._policy


def load_checkpoint_policy(path: str | Path) -> Any:
    """The policy in checkpoint ``path``: a :class:`CheckedPolicy` when these bytes passed these
    checks before, else :func:`agents.loader.load_policy_file` (raising what it raises), whose
    settings are then remembered."""
    path = Path(path)
    key = _key(path)
    folder = _cache_home() / "checked-checkpoints"
    if key is not None:
        entry = _recall(folder / f"{key}.json")
        if entry is not None:
            return CheckedPolicy(path, entry["settings"], entry["names"])
    from agents.loader import load_policy_file

    policy = load_policy_file(path)
    if key is not None and _key(path) == key:  # the bytes loaded are the bytes hashed
        _remember(folder, key, policy)
    return policy


def _cache_home() -> Path:
    """The project's cache folder, as ``smarts.cache.cache_home`` finds it (policies load without
    importing the simulator)."""
    return Path(os.environ.get("SMARTS_CACHE_DIR") or Path.home() / ".cache" / "smarts")


def _key(path: Path) -> str | None:
    try:
        content = hashlib.sha256(path.read_bytes()).hexdigest()
        code = _checking_code()
    except (OSError, metadata.PackageNotFoundError):
        return None  # a file the loader says what is wrong with; or no way to name the checks: no entry
    return hashlib.sha256(f"{content}:{code}".encode()).hexdigest()[:32]


def _checking_code() -> str:
    """A hash of the code that checks a checkpoint (an entry written by other checks is a miss)."""
    global _code_version
    if _code_version is None:
        digest = hashlib.sha256(f"{ENTRY_VERSION}:{metadata.version('torch')}".encode())
        here = Path(__file__).parent
        for name in _CHECKING_CODE:
            digest.update((here / name).read_bytes())
        _code_version = digest.hexdigest()
    return _code_version


def _recall(file: Path) -> dict | None:
    try:
        entry = json.loads(file.read_text())
        settings, names = entry["settings"], entry["names"]
        if set(settings) != set(SETTINGS) or not all(isinstance(n, str) for n in names):
            return None
        os.utime(file)  # used: kept (:data:`KEEP_DAYS`)
        return {"settings": settings, "names": names}
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _remember(folder: Path, key: str, policy: Any) -> None:
    """Write the entry (best effort: a cache that cannot be written only means loading again)."""
    from agents.checkpoint import write_file_atomically  # (torch is loaded: the policy was just read)

    try:
        settings = {name: getattr(policy, name, None) for name in SETTINGS}
        names = sorted(n for n in dir(policy) if not n.startswith("_"))
        data = json.dumps({"version": ENTRY_VERSION, "settings": settings, "names": names}, sort_keys=True)
        write_file_atomically(folder / f"{key}.json", data.encode(), "checked-checkpoint entry")
        old = time.time() - KEEP_DAYS * 86400
        for entry in folder.iterdir():
            with contextlib.suppress(OSError):
                if entry.stat().st_mtime < old:
                    entry.unlink()
    except (OSError, TypeError, ValueError):  # (a write that fails is a CheckpointWriteError, a ValueError)
        pass
