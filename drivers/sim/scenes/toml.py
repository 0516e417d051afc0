"""Scenarios from TOML: a preset's name, seed, duration, sensor and parameters in a file or a string.

Keys (anything else is refused with a one-line :class:`~necviz.core.errors.ProfileError`)::

    name = "tunnel_exit"      # a preset of SCENARIOS (required)
    seed = 3                  # integer in 0..2^32-1, default 0
    duration_s = 2.0          # or duration_us = 2000000 (at most 600 s); default: the preset's own duration
    sensor = "DAVIS346"       # optional: "DAVIS346", "DAVIS240" or {width = .., height = ..}
    [params]                  # the preset's parameters (scenario_params(name))
    step_db = 90
"""

from __future__ import annotations

import os
import tomllib
from pathlib import Path

from necviz.core.checks import check_number
from necviz.core.errors import ParameterError, ProfileError
from necviz.core.limits import MAX_DURATION_S, MAX_SEED
from necviz.core.sensor import DAVIS240, DAVIS346, SensorGeometry
from necviz.drivers.sim.scene import Scene
from necviz.drivers.sim.scenes.preset import US
from necviz.drivers.sim.scenes.registry import SCENARIOS, make_scenario

__all__ = ["load_scenario_spec", "scenario_from_toml"]

_SENSORS = {"DAVIS346": DAVIS346, "DAVIS240": DAVIS240}
_TOML_KEYS = {"name", "seed", "duration_s", "duration_us", "sensor", "params"}


def _number(source: str, key: str, v, **kw):
    """:func:`check_number` for a top-level key, as a :class:`ProfileError` naming the source."""
    try:
        return check_number(f'"{key}"', v, **kw)
    except ParameterError as e:
        raise ProfileError(f"{source}: {e}") from None


def load_scenario_spec(path_or_text: str | os.PathLike) -> dict:
    """Read and check a scenario file (or TOML text: a string containing ``=``) without building it.

    Returns ``{"name", "seed", "duration_us", "sensor", "params"}``; ``seed``/``duration_us`` are
    ``None`` where the file does not set them, ``sensor`` is ``None`` for the default DAVIS346.
    Commands merge their own ``--seed``, ``--duration`` and ``--set`` on top.
    """
    if isinstance(path_or_text, os.PathLike) or (isinstance(path_or_text, str) and "=" not in path_or_text):
        path = Path(path_or_text)
        source = str(path)
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as e:
            raise ProfileError(f"{source}: cannot read scenario file ({e.strerror or e})") from None
        except UnicodeDecodeError as e:
            raise ProfileError(f"{source}: not UTF-8 text at byte {e.start} (a TOML scenario file is UTF-8)") from None
    elif isinstance(path_or_text, str):
        source, text = "scenario TOML", path_or_text
    else:
        raise ProfileError(f"scenario_from_toml needs a path or TOML text, got {type(path_or_text).__name__}")
    try:
        d = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ProfileError(f"{source}: invalid TOML: {e}") from None
    unknown = sorted(set(d) - _TOML_KEYS)
    if unknown:
        raise ProfileError(f"{source}: unknown key(s) {', '.join(unknown)}; accepted: {', '.join(sorted(_TOML_KEYS))}")
    if "name" not in d:
        raise ProfileError(f'{source}: missing key "name" (one of {", ".join(sorted(SCENARIOS))})')
    if d["name"] not in SCENARIOS:
        raise ParameterError(f"{source}: unknown scenario {d['name']!r}; known: {', '.join(sorted(SCENARIOS))}")
    seed = _number(source, "seed", d["seed"], lo=0, hi=MAX_SEED, integer=True) if "seed" in d else None
    if "duration_s" in d and "duration_us" in d:
        raise ProfileError(f"{source}: give either duration_s or duration_us, not both")
    duration_us = None
    if "duration_s" in d:
        duration_us = int(
            round(_number(source, "duration_s", d["duration_s"], lo=0.0, hi=MAX_DURATION_S, lo_open=True) * US)
        )
    elif "duration_us" in d:
        duration_us = _number(
            source, "duration_us", d["duration_us"], lo=0, hi=MAX_DURATION_S * US, lo_open=True, integer=True
        )
    sensor = d.get("sensor")
    if isinstance(sensor, str):
        if sensor not in _SENSORS:
            raise ProfileError(
                f"{source}: unknown sensor {sensor!r}; known: {', '.join(_SENSORS)} "
                "or a table {width = .., height = ..}"
            )
        sensor = _SENSORS[sensor]
    elif isinstance(sensor, dict):
        try:
            sensor = SensorGeometry(sensor["width"], sensor["height"])
        except KeyError as e:
            raise ProfileError(f"{source}: sensor table is missing {e}") from None
        except ParameterError as e:
            raise ProfileError(f"{source}: {e}") from None
    elif sensor is not None and not isinstance(sensor, SensorGeometry):
        raise ProfileError(f'{source}: "sensor" must be a name or a table, got {sensor!r}')
    params = d.get("params", {})
    if not isinstance(params, dict):
        raise ProfileError(f"{source}: [params] must be a table, got {params!r}")
    return {
        "name": d["name"],
        "seed": seed,
        "duration_us": duration_us,
        "sensor": sensor,
        "params": params,
        "source": source,
    }


def scenario_from_toml(path_or_text: str | os.PathLike) -> Scene:
    """Build a scenario from a TOML file path or TOML text (a string containing ``=``); keys: module docstring."""
    spec = load_scenario_spec(path_or_text)
    try:
        return make_scenario(
            spec["name"],
            sensor=spec["sensor"] or DAVIS346,
            duration_us=spec["duration_us"],
            seed=spec["seed"] or 0,
            **spec["params"],
        )
    except ParameterError as e:
        raise ParameterError(f"{spec['source']}: {e}") from None
