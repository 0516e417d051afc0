"""Camera profile files: :func:`load_profile`, :func:`save_profile`, and the shipped profile of the
simulated DAVIS346 (package data ``necviz/profiles/davis346-sim.json``): its file name, how it was made,
and :func:`default_sim_profile`, which reads it. The profile itself is
:class:`necviz.core.camera_profile.CameraProfile` (plain data)."""

from __future__ import annotations

import json
import os
from importlib import resources
from pathlib import Path

from necviz.core.camera_profile import CameraProfile
from necviz.core.errors import ProfileError

#: The shipped profile of the simulated DAVIS346 (package data).
SIM_PROFILE = "davis346-sim.json"

#: How the shipped profile was made (the README repeats it): the calibration scene only, which no
#: evaluation uses; its seeds and duration.
SIM_CALIBRATION = {"scenarios": ["calibration"], "seeds": [0, 1, 2], "duration_s": 6.0}


def default_sim_profile() -> CameraProfile:
    """The camera profile calibrated on the simulated DAVIS346 (``necviz/profiles/davis346-sim.json``).

    Made by ``necviz calibrate --sim calibration --seeds 0..2 --duration 6`` on the default
    simulator (:class:`~necviz.drivers.sim.dvs.DvsParams`, :class:`~necviz.drivers.sim.aps.ApsParams`);
    see :data:`SIM_CALIBRATION`. The calibration scene is used by no evaluation. Its compensation was
    dropped (``a± = b± = 0``): on held-out pairs it made the residual below the bus ceiling worse
    (``calibration.compensation`` in the file; ``docs/calibration.md``).
    """
    ref = resources.files("necviz") / "profiles" / SIM_PROFILE
    with resources.as_file(ref) as path:
        return load_profile(path)


def load_profile(path: str | os.PathLike) -> CameraProfile:
    """Read a profile; any problem raises :class:`ProfileError` naming the file."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ProfileError(f"camera profile {p} does not exist") from None
    except (OSError, UnicodeDecodeError) as e:
        raise ProfileError(f"cannot read camera profile {p}: {e}") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as e:
        raise ProfileError(f"{p}: invalid JSON at line {e.lineno}, column {e.colno}: {e.msg}") from None
    return CameraProfile.from_dict(data, str(p))


def save_profile(profile: CameraProfile, path: str | os.PathLike) -> None:
    """Write a profile atomically (a crash never leaves a half-written file)."""
    from necviz.outputs import write_json

    write_json(Path(path), profile.to_dict(), indent=1)
