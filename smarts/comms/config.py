"""The V2V communication settings of a scenario (its ``comms`` section), defined with the rest of
the scenario spec in ``smarts.core.spec.comms`` and named here for the comms model's users."""

from smarts.core.spec.comms import HEADER_BYTES, PAYLOAD_BYTES_PER_FLOAT, CommsConfig

__all__ = ["HEADER_BYTES", "PAYLOAD_BYTES_PER_FLOAT", "CommsConfig"]
