"""Sensor geometry: the pixel array events and frames refer to."""

from __future__ import annotations

from dataclasses import dataclass, field

from necviz.core.errors import ParameterError

#: Most pixels a sensor may have: 4,194,304 (2048 x 2048; today's largest event sensors have about
#: 1.2 million). A larger size read from a file is damage, and per-pixel state would not fit the
#: memory a replay may use.
MAX_PIXELS = 1 << 22


@dataclass(frozen=True)
class SensorGeometry:
    """Width and height of the pixel array, in pixels (x in [0, width), y in [0, height))."""

    width: int
    height: int
    name: str = field(default="custom", compare=False)

    def __post_init__(self) -> None:
        for label, v in (("width", self.width), ("height", self.height)):
            if not isinstance(v, int) or isinstance(v, bool) or v <= 0 or v > 65535:
                raise ParameterError(f"sensor {label} must be an integer in 1..65535, got {v!r}")
        if self.width * self.height > MAX_PIXELS:
            raise ParameterError(
                f"a sensor of {self.width} x {self.height} pixels is larger than any event camera "
                f"(at most {MAX_PIXELS:,} pixels)"
            )

    @property
    def shape(self) -> tuple[int, int]:
        """NumPy image shape ``(height, width)``."""
        return (self.height, self.width)

    @property
    def num_pixels(self) -> int:
        return self.width * self.height


#: The DAVIS346/DAVIS240 event bus ceiling (events per second, sensor-wide): the most events the
#: readout delivers; a change faster than this loses events.
DAVIS_EVENT_RATE_MAX = 12e6

DAVIS346 = SensorGeometry(346, 260, "DAVIS346")
DAVIS240 = SensorGeometry(240, 180, "DAVIS240")

#: Event bus ceilings of known sensors by ``(width, height)`` (events per second).
KNOWN_EVENT_RATES = {DAVIS346.shape[::-1]: DAVIS_EVENT_RATE_MAX, DAVIS240.shape[::-1]: DAVIS_EVENT_RATE_MAX}


def known_event_rate_max(sensor: SensorGeometry | None) -> float | None:
    """The event bus ceiling of a known sensor (by its size), else ``None``."""
    return None if sensor is None else KNOWN_EVENT_RATES.get((sensor.width, sensor.height))
