"""frictionwatch.drivers: bytes and protocols -> typed stream records (core.types), and back (design.md §2).

Subpackages:
    serial    the input-capture board's serial framing and the tooth / cam source
    can       the CAN frames (DBC, codec, decoder, encoder), the pressure / load source and the results publisher
    logs      MCAP replay logs (writer, reader, scanner, schema, replay source, recorder) and MDF4 CAN logs
    daq       raw DAQ voltage tables -> tooth edges and calibrated pressure records
    assembly  ring buffers, wheel sync and the cycle assembler: stream records -> one ``Cycle`` per 720 deg

Modules here:
    source    ``Source`` (the base of every live / replay source), ``open_source`` (the URL registry) and
              ``StreamRestart`` (the mark of a stream starting again: a looped replay's seam)
    errors    the driver error tree
    timebase  unwrapping the board's 32-bit timer into one int64 tick stream
    sequence  putting frames back in order by their modular sequence counter
    backoff   exponential back-off for reconnecting to a vanished port or bus
    bridge    stream records -> what the hardware would put on the wires, and a player that puts it there
"""

from frictionwatch.drivers.errors import CorruptLog, DeviceLost, DriverError, EndOfStream, FramingError, SyncLost
from frictionwatch.drivers.source import Source, StreamRestart, open_source

__all__ = ["CorruptLog", "DeviceLost", "DriverError", "EndOfStream", "FramingError", "Source", "StreamRestart", "SyncLost",
           "open_source"]
