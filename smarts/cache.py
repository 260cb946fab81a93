"""Where generated files (netconvert output, compiled maps) are cached."""

from __future__ import annotations

import os
from pathlib import Path


def cache_home() -> Path:
    """``$SMARTS_CACHE_DIR`` if set, else ``~/.cache/smarts``."""
    env = os.environ.get("SMARTS_CACHE_DIR")
    return Path(env).expanduser() if env else Path.home() / ".cache" / "smarts"
