"""Camera profile: everything necviz needs to know about one camera, as plain data.

Holds the sensor geometry, the camera response ``g``, the TEDI parameters (``c±`` and the
compensation ``a±, b±``) and the exposure/gain limits. The file is plain JSON::

    {"format": "necviz-camera-profile", "version": 1, "name": "DAVIS346 (default)",
     "sensor": {"width": 346, "height": 260},
     "crf": {"g": [256 numbers], "valid_min": 9, "valid_max": 250},
     "tedi": {"c_on": 0.26, "c_off": 0.24, "a_on": 0, "b_on": 0, "a_off": 0, "b_off": 0},
     "limits": {"exposure_min_us": 10, "exposure_max_us": 30000, "gain_max": 1},
     "calibration": {...}}

``b±`` are in events per pixel per second. ``calibration`` is optional: how the profile was
obtained (``necviz calibrate`` writes the data used and the residuals before and after); it is
kept on load and written back unchanged. Reading and writing the file: :mod:`necviz.profiles`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

from necviz.core.control.controller import CameraLimits
from necviz.core.crf import CameraResponse, default_davis346
from necviz.core.errors import NecvizError, ProfileError
from necviz.core.event_model import TediParams
from necviz.core.sensor import DAVIS346, SensorGeometry

FORMAT = "necviz-camera-profile"
VERSION = 1


@dataclass(frozen=True)
class CameraProfile:
    name: str = "DAVIS346 (default)"
    sensor: SensorGeometry = DAVIS346
    crf: CameraResponse = field(default_factory=default_davis346)
    tedi: TediParams = TediParams()
    limits: CameraLimits = CameraLimits()
    calibration: dict | None = field(default=None, compare=False, hash=False)

    def to_dict(self) -> dict:
        d = {
            "format": FORMAT,
            "version": VERSION,
            "name": self.name,
            "sensor": {"width": self.sensor.width, "height": self.sensor.height},
            "crf": {"g": self.crf.to_list(), "valid_min": self.crf.valid_min, "valid_max": self.crf.valid_max},
            "tedi": asdict(self.tedi),
            "limits": asdict(self.limits),
        }
        if self.calibration is not None:
            d["calibration"] = self.calibration
        return d

    @classmethod
    def from_dict(cls, d: dict, source: str = "profile") -> CameraProfile:
        if not isinstance(d, dict) or d.get("format") != FORMAT:
            raise ProfileError(f'{source}: not a necviz camera profile (missing "format": "{FORMAT}")')
        if d.get("version") != VERSION:
            raise ProfileError(f"{source}: profile version {d.get('version')!r} is not supported (expected {VERSION})")
        cal = d.get("calibration")
        if cal is not None and not isinstance(cal, dict):
            raise ProfileError(f'{source}: section "calibration" must be an object')
        try:
            s = _section(d, "sensor", source)
            c = _section(d, "crf", source)
            t = _section(d, "tedi", source)
            lim = _section(d, "limits", source)
            return cls(
                name=str(d.get("name", "unnamed")),
                sensor=SensorGeometry(
                    _int(s, "width", source), _int(s, "height", source), str(d.get("name", "custom"))
                ),
                crf=CameraResponse(c["g"], c.get("valid_min", 9), c.get("valid_max", 250)),
                tedi=TediParams(**{k: _num(t, k, source) for k in t}),
                limits=CameraLimits(**{k: _num(lim, k, source) for k in lim}),
                calibration=cal,
            )
        except ProfileError:
            raise
        except KeyError as e:
            raise ProfileError(f"{source}: missing field {e}") from None
        except TypeError as e:
            raise ProfileError(f"{source}: {e}") from None
        except NecvizError as e:
            raise ProfileError(f"{source}: {e}") from None


def _section(d: dict, key: str, source: str) -> dict:
    v = d.get(key)
    if not isinstance(v, dict):
        raise ProfileError(f'{source}: section "{key}" is missing or not an object')
    return v


def _num(d: dict, key: str, source: str) -> float:
    v = d[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ProfileError(f'{source}: "{key}" must be a finite number, got {v!r}')
    return float(v)


def _int(d: dict, key: str, source: str) -> int:
    v = d.get(key)
    if isinstance(v, bool) or not isinstance(v, int):
        raise ProfileError(f'{source}: sensor "{key}" must be an integer, got {v!r}')
    return v
