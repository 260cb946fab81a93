"""Errors raised while reading, compiling or querying a road map."""

from __future__ import annotations


class MapError(ValueError):
    """A map file is missing, malformed, or cannot answer a query.

    Messages start with the file concerned so a user with many scenarios knows which one to fix.
    """


class NoRouteError(MapError):
    """No lane sequence connects the requested start and end lanes."""


class MapWarning(UserWarning):
    """A map was loaded, but not entirely as written (e.g. parts netconvert could not convert)."""
