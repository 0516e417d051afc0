"""The package version, in a module of its own: read without importlib.metadata (which costs ~0.1 s at
start-up) and by setuptools at build time (pyproject.toml: dynamic version)."""

__version__ = "0.1.0"
