"""What ``necviz info`` reports: versions, Numba's threading layer, registered sources and controllers."""

from __future__ import annotations

import os
from importlib.metadata import PackageNotFoundError, version

import numba as nb
import numpy as np

from necviz import __version__

PACKAGES = ("numpy", "numba", "llvmlite", "scipy", "opencv-python-headless", "pyusb", "rerun-sdk")


@nb.njit(parallel=True, cache=True)
def _touch_threads(n):
    acc = np.zeros(n)
    for i in nb.prange(n):
        acc[i] = i
    return acc.sum()


def threading_layer() -> str:
    """The layer Numba actually uses (it is only chosen once a parallel function has run)."""
    try:
        _touch_threads(4)
        return f"{nb.threading_layer()} ({nb.config.NUMBA_NUM_THREADS} threads)"
    except Exception as e:  # no usable layer: report it rather than fail
        return f"unavailable ({e})"


def _scenarios() -> list[str]:
    from necviz.drivers.sim.scenes import SCENARIOS

    return sorted(SCENARIOS)


def collect_info() -> dict:
    import necviz.tuned  # noqa: F401 - registers the tuned controllers (navid-tuned, ...), which every command accepts
    from necviz.core.control import CONTROLLERS
    from necviz.drivers import SOURCES

    pkgs = {}
    for name in PACKAGES:
        try:
            pkgs[name] = version(name)
        except PackageNotFoundError:
            pkgs[name] = "not installed"
    return {
        "necviz": __version__,
        "cpu_count": os.cpu_count(),
        "packages": pkgs,
        "numba_threading_layer": threading_layer(),
        "controllers": sorted(CONTROLLERS),
        "sources": sorted(SOURCES),
        "scenarios": _scenarios(),
    }
