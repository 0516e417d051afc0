"""Tuned controllers: every baseline (and NEC) with the parameters ``benchmarks/tuning.py`` chose.

``benchmarks/tuning.py`` evaluates the same number of variants of each controller's parameters on the
same training scenes and seeds and picks one per controller by the same rule (docs/evaluation.md);
it writes the choice to ``necviz/tuned.json``, shipped with the package. :func:`register_tuned`
registers each choice as ``NAME-tuned`` (``navid-tuned``, ``shim-tuned``, ``begin-tuned``,
``nec-tuned``): the registered controller ``NAME`` starting from the chosen options, so every
command, sweep and the dashboard accept it by name, and a table can show the published and the
tuned baseline side by side. Controllers without parameters (the DAVIS built-in rule, a fixed
exposure) are not tuned; the file says so.

The file (plain JSON)::

    {"command": "...", "training": {"scenarios": [...], "seeds": [...], ...}, "rule": "...",
     "controllers": {"navid": {"label": "...", "params": {"ev_per_unit": 0.02, ...}, ...}, ...},
     "not_tuned": {"builtin": "why", ...}}
"""

from __future__ import annotations

import json
from pathlib import Path

from necviz.core.control import CONTROLLERS, register_controller
from necviz.core.errors import ParameterError

#: the committed choice of ``benchmarks/tuning.py``
TUNED_FILE = Path(__file__).with_name("tuned.json")
#: suffix of a tuned controller's name
SUFFIX = "-tuned"


def load_tuned(path: Path | str = TUNED_FILE) -> dict:
    """The tuning file as a dict (``{}`` when there is none).

    Raises
    ------
    ParameterError
        The file exists but is not a tuning file (unreadable JSON, no ``controllers`` table).
    """
    p = Path(path)
    if not p.is_file():
        return {}
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:
        raise ParameterError(f"{p}: not a tuning file ({e})") from None
    if not isinstance(data, dict) or not isinstance(data.get("controllers"), dict):
        raise ParameterError(f"{p}: not a tuning file (no 'controllers' table)")
    return data


def register_tuned(path: Path | str = TUNED_FILE) -> list[str]:
    """Register ``NAME-tuned`` for every controller in the tuning file; returns the names registered.

    Idempotent (registering again replaces the entries with the same values).

    Raises
    ------
    ParameterError
        A tuned controller whose base is not registered, or parameters its options refuse.
    """
    data = load_tuned(path)
    names = []
    for base, entry in data.get("controllers", {}).items():
        if base not in CONTROLLERS:
            raise ParameterError(f"{path}: tuned controller {base!r} is not a registered controller")
        if not isinstance(entry, dict) or not isinstance(entry.get("params"), dict):
            raise ParameterError(f"{path}: controllers.{base} needs a 'params' table")
        parent = CONTROLLERS[base]
        name = base + SUFFIX
        doc = f"{base} with the parameters benchmarks/tuning.py chose ({entry.get('label', 'tuned')})"
        register_controller(name, parent.cls, parent.build, doc, {**parent.defaults, **entry["params"]})
        names.append(name)
    return names


#: registered at import, once per process (necviz.options imports this module)
REGISTERED = register_tuned()

__all__ = ["REGISTERED", "SUFFIX", "TUNED_FILE", "load_tuned", "register_tuned"]
