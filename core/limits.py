"""Limits every input obeys, wherever it comes from (the command line, a scenario or sweep file)."""

#: The longest simulated scene, seconds (the command line's ``--duration`` and a scenario file's ``duration_s``).
MAX_DURATION_S = 600.0
#: The largest seed (NumPy's seed sequences take any integer; 32 bits keep files portable).
MAX_SEED = 2**32 - 1
