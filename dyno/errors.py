"""One exception root for the project (gpiozero's exc.py style).

Each subclass also inherits the matching built-in type so callers that only
know the built-ins still catch them.
"""


class DynoError(Exception):
    """Root of every error dyno raises on purpose."""


class ConfigError(DynoError, ValueError):
    """A configuration, calibration or data file is malformed.

    The message names the file and the field and says what is expected; the
    CLI turns it into a one-line error and exit code 2.
    """

    def __init__(self, path, field, expected):
        self.path = str(path)
        self.field = field
        self.expected = expected
        super().__init__(f"{self.path}: {field}: {expected}")


class FrameError(DynoError, ValueError):
    """A frame failed a protocol check; ``cause`` is the rejection counter key."""

    def __init__(self, cause, detail=""):
        self.cause = cause
        super().__init__(f"{cause}: {detail}" if detail else cause)


class TransportError(DynoError, OSError):
    """A bus transfer failed (NACK, timeout, short read)."""


class SafetyAbort(DynoError, RuntimeError):
    """The test controller aborted to the safe state."""


class DidNotConverge(DynoError, ArithmeticError):
    """A numerical model failed to converge; the message names the case."""


class GrossSlip(DynoError):
    """A physical state, not a numerical failure: the belt cannot transmit the load (no steady solution).

    The message names the case and the pulley whose tension ratio reached its
    capstan/Gerbert bound (or whose speed collapsed).
    """


# What a belt-model solve can raise besides bad input: callers that tolerate a failed point catch both.
MODEL_FAILURES = (DidNotConverge, GrossSlip)
