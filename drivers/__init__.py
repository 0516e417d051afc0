"""Sources of events and frames: the closed-loop simulator, the DAVIS driver and the file replayers.

Every source implements :class:`necviz.drivers.source.Source`; :data:`SOURCES` names them for
``necviz info`` (values are import paths, so listing them imports nothing heavy).
"""

#: name -> "module:attribute" of the source's class or factory.
SOURCES: dict[str, str] = {
    "sim": "necviz.drivers.sim.camera:SimRig",
    "davis": "necviz.drivers.davis:open_camera",
    "replay": "necviz.drivers.replay:open_recording",
}
