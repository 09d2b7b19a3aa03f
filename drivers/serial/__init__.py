"""The input-capture board's serial link (docs/protocols.md §2).

    codec  the framing on bytes alone: frame types, ``Encoder`` and the resyncing ``Decoder``
    teeth  ``SerialSource``: tooth and cam edges from the board over a serial port (``serial:`` URLs)
"""

from frictionwatch.drivers.serial.codec import CamFrame, Decoder, Encoder, HeartbeatFrame, InfoFrame, TeethFrame
from frictionwatch.drivers.serial.teeth import SerialSource

__all__ = ["CamFrame", "Decoder", "Encoder", "HeartbeatFrame", "InfoFrame", "SerialSource", "TeethFrame"]
