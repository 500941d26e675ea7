"""The exceptions stereotac raises: one base class, one subclass per kind.

Each kind is also the built-in exception Python code expects for it, so
``except ValueError`` catches bad input and ``except OSError`` a missing file.
"""


class StereotacError(Exception):
    """Base class of every error stereotac raises."""


class BadInputError(StereotacError, ValueError):
    """Inputs that cannot be right: an array of the wrong dtype, shape or size, frames
    that do not fit the model, a file that is not a model or calibration, a setting out
    of range. The message names the input and the fix."""


class IoError(StereotacError, OSError):
    """A file could not be read or written (missing, unreadable, no space)."""


class DeviceError(StereotacError):
    """The sensor could not be reached, or it answered wrongly."""
