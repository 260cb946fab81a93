"""Ready-made agents by locator (see ``zoo.registry``)."""

from zoo.registry import ZOO, make_policy

__all__ = ["ZOO", "make_policy"]
