"""The built-in traffic model: IDM car following, MOBIL lane changes and right of way at
junctions, vectorised over all vehicles on the compiled lane graph (no external simulator)."""

from smarts.traffic.builtin.provider import BuiltinTrafficProvider

__all__ = ["BuiltinTrafficProvider"]
