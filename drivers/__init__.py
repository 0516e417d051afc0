"""Sources of events and frames: the closed-loop simulator, the DAVIS driver and the file replayers.

Every source implements :class:`necviz.drivers.source.Source`; :data:`SOURCES` names them for
``necviz info`` (values are import paths, so listing them imports nothing heavy).
"""

if __name__ != "necviz.drivers":  # the folder imported as a top-level package (e.g. from the repository root)
    raise ImportError(
        f"this folder is the package necviz.drivers, not {__name__!r}: import necviz.drivers "
        "(installed by `pip install -e .` from the repository root)"
    )


#: name -> "module:attribute" of the source's class or factory.
SOURCES: dict[str, str] = {
    "sim": "necviz.drivers.sim.rig:SimRig",
    "davis": "necviz.drivers.davis:open_camera",
    "replay": "necviz.drivers.recordings:open_recording",
}
