"""Error types that name the user's mistake in one line.

Every check in ``necviz.core`` raises a subclass of :class:`NecvizError`
(itself a ``ValueError``), so the command line can print ``error: <message>``
instead of a traceback for bad input.
"""


class NecvizError(ValueError):
    """Base class for errors caused by bad input or parameters."""


class EventFormatError(NecvizError):
    """An event array has the wrong dtype, unsorted time or coordinates outside the sensor."""


class FrameFormatError(NecvizError):
    """A frame has a wrong image type, a non-positive exposure or a nonsense gain."""


class ParameterError(NecvizError):
    """A parameter is NaN, out of range or inconsistent with another."""


class OptionError(ParameterError):
    """An option object refused a value: ``field`` names it as the library does (``"ClipOptions.before_s"``),
    and the message says why in the same terms. The command line shows its flag instead
    (:func:`necviz.flags.in_flag_terms`)."""

    def __init__(self, field: str, message: str):
        super().__init__(message)
        self.field = field
        self.message = message


class ProfileError(NecvizError):
    """A camera profile file is missing, unreadable or inconsistent."""


class NotAnchoredError(NecvizError):
    """An estimate was requested before any usable frame anchored the estimator."""


class StreamError(NecvizError):
    """Packets arrived out of order or a frame's exposure was never announced."""
