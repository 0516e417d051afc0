"""The shipped camera profile of the simulated DAVIS346 (package data ``necviz/profiles/davis346-sim.json``):
its file name, how it was made, and :func:`default_sim_profile`, which reads it."""

from __future__ import annotations

from importlib import resources

from ..core.profile import CameraProfile, load_profile

#: The shipped profile of the simulated DAVIS346 (package data).
SIM_PROFILE = "davis346-sim.json"

#: How the shipped profile was made (the README repeats it): the calibration scene only, which no
#: evaluation uses; its seeds and duration.
SIM_CALIBRATION = {"scenarios": ["calibration"], "seeds": [0, 1, 2], "duration_s": 6.0}


def default_sim_profile() -> CameraProfile:
    """The camera profile calibrated on the simulated DAVIS346 (``necviz/profiles/davis346-sim.json``).

    Made by ``necviz calibrate --sim calibration --seeds 0..2 --duration 6`` on the default
    simulator (:class:`~necviz.drivers.sim.dvs.DvsParams`, :class:`~necviz.drivers.sim.aps.ApsParams`);
    see :data:`SIM_CALIBRATION`. The calibration scene is used by no evaluation.
    """
    ref = resources.files("necviz") / "profiles" / SIM_PROFILE
    with resources.as_file(ref) as path:
        return load_profile(path)
