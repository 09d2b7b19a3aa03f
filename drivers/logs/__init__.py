"""Replay logs (docs/replay-format.md): MCAP written and read back damage-tolerantly, and MDF4 CAN logs.

    mcap_log       ``LogWriter`` (and ``LogReader`` re-exported)
    mcap_reader    ``LogReader``, the damage-tolerant reader, and the message ``Codec`` interface
    mcap_scan      one linear pass over an MCAP file that resyncs after damage, chunk decoding
    mcap_schema    the protobuf messages built at run time, metadata keys, the log-time rule
    mcap_frame_kernel  a pressure frame's and a tooth / cam batch's bytes by one compiled pass (upb where it declines)
    mcap_batching  ``Batcher``: stream records -> log messages of about one span each
    mcap_replay    ``McapSource``: a log replayed as a live source (``mcap:`` URLs)
    recorder       ``Recorder``: the raw input of a live session into rotating, size-bounded logs
    mdf4           ``Mdf4Source``: CAN bus logs in ASAM MDF4 replayed as a source (``mdf4:`` URLs);
                   ``j1939_engine_speed``: J1939 EEC1 engine speed (SPN 190) of any bus log, no DBC needed
"""

from frictionwatch.drivers.logs.mcap_log import DEFAULT_CHUNK_BYTES, LogWriter
from frictionwatch.drivers.logs.mcap_reader import Codec, LogReader, ProtobufCodec
from frictionwatch.drivers.logs.mcap_replay import McapSource
from frictionwatch.drivers.logs.mdf4 import Mdf4Source
from frictionwatch.drivers.logs.recorder import Recorder

__all__ = ["DEFAULT_CHUNK_BYTES", "Codec", "LogReader", "LogWriter", "McapSource", "Mdf4Source", "ProtobufCodec",
           "Recorder"]
