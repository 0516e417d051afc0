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

from importlib import import_module

from necviz._version import __version__

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


def __getattr__(name):
    if name in _API:
        module, attr = _API[name].split(":")
        value = getattr(import_module(module), attr)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'necviz' has no attribute {name!r}")
