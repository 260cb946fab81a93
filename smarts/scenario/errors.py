"""Errors raised while reading scenarios and building their maps."""

from __future__ import annotations


class ScenarioError(ValueError):
    """A scenario file, field or name is invalid; the message names where and what was expected."""


class NetconvertError(RuntimeError):
    """netconvert failed on a generated map; the message carries its stderr."""
