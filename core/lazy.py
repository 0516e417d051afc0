"""A package's public names imported on first use (PEP 562), so importing the package stays light.

``necviz --version`` must not load NumPy, Numba or Rerun; the packages that gather a public API
(``necviz``, ``necviz.core``, ``necviz.calibration``, ``necviz.sweeps``) therefore name where each
export lives and import it when it is first read.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from importlib import import_module


def lazy_exports(package: str, where: dict[str, str]) -> tuple[Callable[[str], object], Callable[[], list[str]]]:
    """The module ``__getattr__`` and ``__dir__`` of ``package``, whose exports live in other modules.

    Parameters
    ----------
    package : str
        The package's ``__name__``.
    where : dict
        Export name -> the module that defines it (absolute, or relative to ``package`` with a
        leading dot), as ``"module:attribute"`` where the attribute's name differs.

    Returns
    -------
    tuple
        ``(__getattr__, __dir__)`` for the package's namespace. A name is imported once: its value
        then sits in the namespace like any other global.
    """
    namespace = sys.modules[package].__dict__

    def __getattr__(name: str) -> object:
        if name not in where:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        module, _, attribute = where[name].partition(":")
        value = getattr(import_module(module, package), attribute or name)
        namespace[name] = value
        return value

    def __dir__() -> list[str]:
        return sorted({*namespace, *where})

    return __getattr__, __dir__
