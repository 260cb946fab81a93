"""Fixtures shared across test folders."""

import shutil

import pytest

from smarts import cache
from smarts.maps.loader import clear_memory_cache


@pytest.fixture
def fresh_fallback(monkeypatch: pytest.MonkeyPatch):
    """No temporary cache and no warning given yet in this process; removes what the test made."""
    monkeypatch.setattr(cache, "_fallback", None)
    monkeypatch.setattr(cache, "_warned", set())
    yield
    if cache._fallback is not None:
        shutil.rmtree(cache._fallback, ignore_errors=True)
    clear_memory_cache()  # maps loaded from the removed folder
