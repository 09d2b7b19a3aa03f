"""Driver error tree (after python-can's can/exceptions.py).

    DriverError                 base of everything a driver raises on bad input or a lost device
    ├── FramingError            a frame failed its sync, length or CRC check (counted, stream goes on)
    ├── SyncLost                the crank-wheel pattern no longer matches (cycle skipped, resync)
    ├── CorruptLog              a log file is truncated or damaged beyond the readable part
    ├── DeviceLost              a port or bus vanished (the source reconnects with back-off)
    └── EndOfStream             a finite source (log replay) has nothing more to give

Bad arguments are plain ``ValueError``. Foreign errors are re-raised ``from`` the original.
"""


class DriverError(Exception):
    """Base of the driver errors."""


class FramingError(DriverError):
    pass


class SyncLost(DriverError):
    pass


class CorruptLog(DriverError):
    pass


class DeviceLost(DriverError):
    pass


class EndOfStream(DriverError):
    pass
