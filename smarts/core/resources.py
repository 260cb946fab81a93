"""Files that ship with the package, found the same way in every kind of install.

The YAML configs (training tasks, benchmark suites, metric constants) are edited in the checkout's
top-level ``configs/`` folder and installed as the package ``smarts.configs`` (``pyproject.toml``
maps the folder to that name). They are located through :mod:`importlib.resources`, so a wheel or
``pip install .`` reads the copies in site-packages and a checkout (editable install) reads its
``configs/``.
"""

from __future__ import annotations

import importlib.resources
from pathlib import Path

CONFIGS_PACKAGE = "smarts.configs"
"""The importable name of the ``configs/`` folder in an install."""


def configs_dir() -> Path:
    """The folder that holds the shipped configs (``train/``, ``benchmark/``).

    It is looked up beside the ``smarts`` package that was imported: ``smarts/configs`` in an
    install, else the checkout's ``configs/`` next to ``smarts/`` (an editable install, or the
    source tree on ``sys.path``). So a checkout always reads its own YAML, even when the
    environment has another copy of the package installed.
    """
    installed = importlib.resources.files("smarts").joinpath("configs")
    if installed.is_dir():
        if not isinstance(installed, Path):  # a zipped install
            raise RuntimeError(f"{CONFIGS_PACKAGE} is not a folder on disk ({installed!r}); install smarts unzipped")
        return installed
    return Path(__file__).resolve().parents[2] / "configs"


def config_path(*parts: str) -> Path:
    """A shipped config file or folder, e.g. ``config_path("train", "platoon.yaml")``."""
    return configs_dir().joinpath(*parts)
