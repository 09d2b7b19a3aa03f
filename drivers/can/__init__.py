"""The CAN side (docs/protocols.md §3): pressure and load in, results out.

    codec        the shipped DBC (frictionwatch.dbc), the byte layouts derived from it, J1939 ids and encoders
    decoder      ``CanDecoder``: CAN frames -> PressureBlock / LoadSample records, batch-vectorised
    encoder      ``PressureEncoder``: blocks of samples -> CAN messages, as the DAQ firmware sends them
    pressure     ``CanSource``: pressure and generator load from a CAN / CAN FD bus (``can:`` URLs)
    results_bus  the optional results PGN: ``encode_results`` / ``decode_results`` and ``ResultsPublisher``
"""

from frictionwatch.drivers.can.codec import FD_SAMPLES, RAW_INVALID, RAW_SATURATED, encode_load, layouts, load_dbc
from frictionwatch.drivers.can.decoder import CanDecoder
from frictionwatch.drivers.can.encoder import PressureEncoder
from frictionwatch.drivers.can.pressure import CanSource
from frictionwatch.drivers.can.results_bus import ResultSet, ResultsPublisher, decode_results, encode_results

__all__ = ["FD_SAMPLES", "RAW_INVALID", "RAW_SATURATED", "CanDecoder", "CanSource", "PressureEncoder", "ResultSet",
           "ResultsPublisher", "decode_results", "encode_load", "encode_results", "layouts", "load_dbc"]
