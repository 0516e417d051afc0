"""The calibration's default settings, as plain values (no NumPy): the command line shows them in
``necviz calibrate --help`` without loading the fit."""

from __future__ import annotations

from typing import Any

#: Frame-pair selection (:class:`necviz.calibration.pairs.PairCollector`).
DEFAULTS: dict[str, Any] = {
    "min_change": 0.5,
    "min_pixels": 200,
    "max_pixels": 5_000,
    "max_pairs": 200,
    "max_bytes": 400_000_000,
    "max_gap_us": 1_000_000,
    "max_lag": 8,
    "static_events": 0.05,
    "continuation": True,
}

#: Lower bound of the compensation knee b/a (events per pixel per second): below it a pixel's events
#: are taken at face value. A third of the DAVIS346's whole-array bus ceiling (12 Mev/s / 89,960
#: pixels = 133 ev/s per pixel), far below its refractory limit (~10 kev/s).
DEFAULT_SLOW_RATE = 50.0

#: Loss of the least-squares fit (SciPy ``least_squares``): see :func:`necviz.calibration.fit.calibrate_collected`.
DEFAULT_LOSS = "linear"
DEFAULT_F_SCALE = 0.25

__all__ = ["DEFAULTS", "DEFAULT_F_SCALE", "DEFAULT_LOSS", "DEFAULT_SLOW_RATE"]
