"""Errors raised while reading scenarios and building their maps (defined in ``smarts.core.errors``;
kept here so existing imports keep working)."""

from smarts.core.errors import NetconvertError, ScenarioError

__all__ = ["NetconvertError", "ScenarioError"]
