"""necviz: neuromorphic exposure control (NEC) toolkit and Rerun dashboard.

Every command is a function taking small option objects, so a script or notebook runs what the
command line runs::

    import necviz

    necviz.run_demo(necviz.DemoOptions(necviz.SceneOptions("tunnel_exit", duration_s=1.0)),
                    necviz.ViewerOptions(save="demo.rrd"))
    table = necviz.run_compare(necviz.CompareOptions(seeds=3, sift=False))
    necviz.run_replay(necviz.ReplayOptions("run.aedat4"), necviz.ViewerOptions(spawn=True))
    necviz.run_live(necviz.LiveOptions(device="emulated"))

The library underneath: :mod:`necviz.core` (estimators, controllers, metrics),
:mod:`necviz.drivers` (simulator, DAVIS driver, readers), :mod:`necviz.pipeline` (the closed
loop), :mod:`necviz.dashboard.sink` (Rerun), :mod:`necviz.layouts` (blueprints).
"""

import os


def _numba_cache_fallback() -> None:
    """Give Numba a writable cache folder when neither of its own is (before Numba is imported).

    Numba caches compiled kernels (``cache=True``) in a ``__pycache__`` beside each source file, else
    in ``$XDG_CACHE_HOME/numba`` (``~/.cache/numba``); when neither can be written (an installed
    package and an unwritable home folder) it refuses to compile the first cached function with a
    traceback. Then the cache goes to ``<temp>/necviz-numba-<uid>`` (``NUMBA_CACHE_DIR``).
    """
    if os.environ.get("NUMBA_CACHE_DIR"):
        return
    import tempfile
    from importlib.util import find_spec

    def writable(folder: str) -> bool:
        probe = folder
        while not os.path.isdir(probe):  # the nearest existing folder must let us create the rest
            parent = os.path.dirname(probe)
            if parent == probe:
                return False
            probe = parent
        return os.access(probe, os.W_OK | os.X_OK)

    roots = [os.path.dirname(__file__)]
    for name in ("necviz.core", "necviz.drivers"):
        try:
            spec = find_spec(name)
        except (ImportError, ValueError):
            spec = None
        if spec is not None and spec.submodule_search_locations:
            roots += list(spec.submodule_search_locations)
    in_tree = all(writable(os.path.join(r, "__pycache__")) for r in roots)
    home = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    if in_tree or writable(os.path.join(home, "numba")):
        return
    folder = os.path.join(tempfile.gettempdir(), f"necviz-numba-{os.getuid() if hasattr(os, 'getuid') else 0}")
    try:
        os.makedirs(folder, mode=0o700, exist_ok=True)
    except OSError:
        return
    os.environ["NUMBA_CACHE_DIR"] = folder
    import sys

    config = getattr(sys.modules.get("numba"), "config", None)
    if config is not None:  # Numba imported before necviz: its configuration is read already
        config.CACHE_DIR = folder


_numba_cache_fallback()
# Rerun's file writer logs a full disk to the terminal before necviz reports it in its own line
# (necviz.dashboard.viewer.flush_stream); a RUST_LOG the user set is left alone.
os.environ.setdefault("RUST_LOG", "warn,re_log_encoding::rrd=off")
# OpenCV decodes images up to 2^30 pixels by default: a small PNG of a damaged recording could claim
# gigabytes. No frame of an event camera exceeds necviz.core.sensor.MAX_PIXELS (2048 x 2048).
os.environ.setdefault("OPENCV_IO_MAX_IMAGE_PIXELS", str(1 << 22))

from necviz._version import __version__  # noqa: E402 - after the environment is set for what follows
from necviz.core.lazy import lazy_exports  # noqa: E402

# name -> "module:attribute", imported on first use (importing necviz stays light for the CLI)
_API = {
    "run_demo": "necviz.commands.demo:run",
    "run_replay": "necviz.commands.replay:run",
    "run_live": "necviz.commands.live:run",
    "run_compare": "necviz.commands.compare:run",
    **{
        n: f"necviz.options:{n}"
        for n in (
            "ClipOptions",
            "VideoOptions",
            "CompareOptions",
            "DemoOptions",
            "LiveOptions",
            "ReplayOptions",
            "SceneOptions",
            "ShowOptions",
            "TuneOptions",
            "ViewerOptions",
        )
    },
}

__all__ = ["__version__", *_API]


__getattr__, __dir__ = lazy_exports(__name__, _API)
