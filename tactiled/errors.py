"""The tactiled exception tree.

Everything tactiled raises on purpose derives from :class:`TactiledError`, so the process edge
(CLI, daemon) can turn it into one clear log line and an exit code.  A bad argument is a plain
``ValueError`` naming the offending value.
"""

from __future__ import annotations


class TactiledError(Exception):
    """Root of all tactiled errors."""


class ConfigError(TactiledError, ValueError):
    """Invalid configuration: the message names the offending key."""


class FrameError(TactiledError):
    """Corrupt, truncated or malformed frame data (wire bytes or frame files)."""


class CalibrationError(TactiledError):
    """A calibration file or table that cannot be used."""


class FitError(TactiledError):
    """A fit that cannot be attempted at all (the fitter itself reports failures in FitResult)."""


class DriverError(TactiledError):
    """A frame source failed."""


class DeviceTimeoutError(DriverError, TimeoutError):
    """A device stopped sending within its timeout."""


class DeviceConnectionError(DriverError, ConnectionError):
    """A device could not be opened or vanished."""
