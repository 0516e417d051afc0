"""Sources of events and frames (live DAVIS driver, file replayers, closed-loop simulator).

Every source registers its name in :data:`SOURCES`; none has landed yet.
"""

#: name -> source factory; filled by the simulator, DAVIS and replay drivers as they land.
SOURCES: dict[str, object] = {}
