"""``njit``: numba's ``njit(cache=True)`` with an on-disk cache that is stale when a module of the
project that the kernel's module imports changes, not only the kernel's own file.

Why: numba checks a cached function against its own source file only, yet the compiled code
also holds what came from other modules: the code of the compiled functions it calls and the
values of the constants it reads (``COLUMN["x"]`` of ``smarts.core.vehicle_table``, a role or
map code). Edit one of those (a column reordered, a stage fixed) and every kernel of another
file would go on running the old code from the cache, giving wrong numbers that no test
notices. Here a kernel's cache stamp also covers the contents of every module of its own
top-level package that its module imports, directly or through those modules, found by reading
their import lines once per process: 10-15 ms for the simulator's modules (parsing them would
take 0.2 s), 2% of importing them.

Every cached kernel of ``smarts`` is declared with :func:`njit` (``tests/test_compiled.py``).
"""

from __future__ import annotations

import functools
import hashlib
import os
import pickle

import numba
from numba.core import caching

__all__ = ["njit", "imported_files"]


def njit(*args, **options):
    """``numba.njit(cache=True, **options)`` whose cache also follows the module's imports.
    Used as ``@njit`` or ``@njit(nogil=True, ...)``."""

    def decorate(py_func):
        py_func.__cache_follows_imports__ = True  # read by _FollowingLocator, before numba caches it
        # Without the locator (a numba whose cache machinery moved) nothing is cached: slower
        # starts, never stale code.
        return numba.njit(cache=_FOLLOWING, **options)(py_func)

    if args and callable(args[0]) and not options:
        return decorate(args[0])
    return decorate


def _import_statements(text: bytes) -> list[str]:
    """The import statements of a module's source, a ``from m import (...)`` whole, comments
    dropped: every line that starts with ``from`` or ``import`` (indented too, so imports inside
    functions count). Found with ``bytes.find``: a regular expression over the whole text takes
    ten times as long."""
    found = []
    at = text.find(b"import")
    while at >= 0:
        start = text.rfind(b"\n", 0, at) + 1
        end = text.find(b"\n", at)
        end = len(text) if end < 0 else end
        line = text[start:end].lstrip()
        if line.startswith((b"from ", b"import ")):
            if b"(" in line and b")" not in line:
                close = text.find(b")", at)
                end = len(text) if close < 0 else close + 1
            statement = text[start:end].decode(errors="replace")
            found.append(" ".join(part.partition("#")[0] for part in statement.split("\n")).strip())
        at = text.find(b"import", end)
    return found


@functools.cache
def _source_files(base: str, package: str) -> frozenset[str]:
    """Every ``.py`` file of the package (one walk, instead of a look-up per imported name)."""
    found = set()
    for folder, folders, names in os.walk(os.path.join(base, package)):
        folders[:] = [f for f in folders if f != "__pycache__"]
        found.update(os.path.join(folder, name) for name in names if name.endswith(".py"))
    return frozenset(found)


def _module_file(base: str, name: str) -> str | None:
    files = _source_files(base, name.split(".")[0])
    stem = os.path.join(base, *name.split("."))
    for path in (stem + ".py", os.path.join(stem, "__init__.py")):
        if path in files:
            return path
    return None


@functools.cache
def _imports(path: str, module: str, base: str) -> tuple[tuple[str, str], ...]:
    """(file, module name) of the modules of ``module``'s top-level package that ``path`` (the
    module ``module``) imports: a ``from m import x`` counts ``m`` and, where ``x`` is a module, ``m.x``;
    an import of ``a.b`` runs ``a`` too. (Plain strings: path objects would take ten times as long.)"""
    package = module.split(".")[0]
    own_package = module if path.endswith("__init__.py") else module.rpartition(".")[0]
    with open(path, "rb") as f:
        statements = _import_statements(f.read())
    names: list[str] = []
    for statement in statements:
        if statement.startswith("import "):
            names += [n.split()[0] for n in statement[7:].split(",") if n.strip()]
            continue
        name, _, imported = statement[5:].partition(" import ")
        name = name.strip()
        if name.startswith("."):  # relative: resolved against this module's package
            level = len(name) - len(name.lstrip("."))
            anchor = own_package.split(".")[: len(own_package.split(".")) - level + 1]
            name = ".".join([*anchor, name.lstrip(".")]).strip(".")
        names.append(name)
        names += [f"{name}.{n.split()[0]}" for n in imported.strip().strip("()").split(",") if n.strip()]
    parts = [n.split(".") for n in names if n.split(".")[0] == package]
    modules = {".".join(p[:k]) for p in parts for k in range(1, len(p) + 1)}  # with the packages it runs
    found = ((_module_file(base, m), m) for m in sorted(modules))
    return tuple((f, m) for f, m in found if f is not None)


@functools.cache
def imported_files(path: str, module: str) -> tuple[str, ...]:
    """The source files of the modules of ``module``'s top-level package that the module at
    ``path`` imports, directly or through them (itself included), sorted."""
    own = os.path.abspath(path)
    base = own
    for _ in range(module.count(".") + 1 + (os.path.basename(own) == "__init__.py")):
        base = os.path.dirname(base)
    seen, todo = {own: module}, [(own, module)]
    while todo:
        for file, name in _imports(*todo.pop(), base):
            if file not in seen:
                seen[file] = name
                todo.append((file, name))
    return tuple(sorted(seen))


@functools.cache
def _file_digest(path: str) -> bytes:
    with open(path, "rb") as f:
        return hashlib.blake2b(f.read(), digest_size=16).digest()


@functools.cache
def _imports_stamp(path: str, module: str) -> str:
    digest = hashlib.blake2b(digest_size=16)
    for file in imported_files(path, module):
        digest.update(file.encode() + b"\0" + _file_digest(file))
    return digest.hexdigest()


class _FollowingLocator:
    """The cache locator of an :func:`njit` kernel: numba's own, with a source stamp that also
    covers the contents of the modules its module imports."""

    def __init__(self, inner, py_func):
        self._inner, self._module = inner, py_func.__module__
        self._path = os.path.abspath(py_func.__code__.co_filename)

    @classmethod
    def from_function(cls, py_func, py_file):
        if not getattr(py_func, "__cache_follows_imports__", False):
            return None
        for base in caching.CacheImpl._locator_classes:
            inner = None if base is cls else base.from_function(py_func, py_file)
            if inner is not None:
                return cls(inner, py_func)
        return None

    def get_source_stamp(self):
        return self._inner.get_source_stamp(), _imports_stamp(self._path, self._module)

    def __getattr__(self, name: str):
        return getattr(self._inner, name)


def _register_locator() -> bool:
    """Put ``_FollowingLocator`` first among numba's cache locators (once); False where this
    numba has no such list."""
    classes = getattr(getattr(caching, "CacheImpl", None), "_locator_classes", None)
    if not isinstance(classes, list):
        return False
    if not any(c.__name__ == "_FollowingLocator" for c in classes):
        classes.insert(0, _FollowingLocator)
    return True


def _tolerate_stale_cache_indexes() -> None:
    """Let numba treat a cache index that no longer unpickles as stale.

    numba's on-disk cache reads an index's source stamp and its entries in one unpickling, before
    comparing the stamp, and each entry's signature names the record classes of its arguments by
    module path. Once such a class is renamed or removed, every stale index that names it raises
    on load and the kernel cannot be compiled at all, where numba would otherwise find the index
    stale, compile again and overwrite it. Reading such an index as empty does exactly that."""
    cls = getattr(caching, "IndexDataCacheFile", None)
    load = getattr(cls, "_load_index", None)
    if load is None or getattr(load, "tolerates_stale_classes", False):
        return

    def _load_index(self):
        try:
            return load(self)
        except (AttributeError, ImportError, pickle.UnpicklingError, EOFError, TypeError, ValueError):
            return {}

    _load_index.tolerates_stale_classes = True
    cls._load_index = _load_index


_FOLLOWING = _register_locator()
_tolerate_stale_cache_indexes()
