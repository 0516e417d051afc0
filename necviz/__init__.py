"""necviz: neuromorphic exposure control (NEC) toolkit and Rerun dashboard."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("necviz")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0+unknown"
