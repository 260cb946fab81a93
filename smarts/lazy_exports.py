"""A package's public names imported from its submodules on first use (PEP 562), so that importing
the package (every command-line tool names a map error, every ``smarts replay`` command imports the
replay package) does not import the heavy submodules behind the names it does not use."""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any


def lazy_exports(package: str, exports: dict[str, str], namespace: dict[str, Any]) -> Callable[[str], Any]:
    """The package's module ``__getattr__``: ``exports`` maps a public name to the submodule of
    ``package`` that defines it; a name, once imported, is kept in ``namespace`` (the package's
    ``globals()``), so it is looked up only once."""

    def __getattr__(name: str) -> Any:
        if name in exports:
            value = getattr(importlib.import_module(f"{package}.{exports[name]}"), name)
            namespace[name] = value
            return value
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    return __getattr__
