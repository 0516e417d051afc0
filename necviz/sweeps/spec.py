"""Sweep files (TOML): read, check and expand into runs, each keyed by a hash of its full spec.

A sweep file lists scenarios, controllers, seeds and the parameters to vary; the expanded grid is
the Cartesian product scenario entry × its parameter combinations × simulator overrides × camera
profile × controller entry × its parameter combinations × seed. Keys (anything else is refused
with a one-line :class:`~necviz.core.errors.ParameterError` naming the key)::

    name = "ablation"                  # optional: a title for the report
    seeds = "0..9"                     # "a..b" (inclusive), "1,5,9" or a list [1, 5, 9]
    duration_s = 2.0                   # optional: simulated seconds (default: each scenario's own)
    sift = false                       # SIFT inliers between frames (about 40 ms a frame: opt-in)
    markers = true                     # fiducial-marker detection per frame (about 2 ms a frame; default false)
    metrics = ["saturated_frames_50", "recovery_ms"]   # what the report shows (default: every metric)
    profiles = ["default", "mismatch.json"]            # optional: camera profiles for the controllers
    sim = { "dvs.c_on" = [0.2, 0.3] }  # optional: simulator overrides for every scenario (a grid)
    controllers = ["fixed", { name = "nec", params = { goal = [100, 110] } }]
    # a labelled variant, KIND@LABEL, names a rung of a ladder in the report: { name = "nec@bound", params = {...} }
    scenarios = ["flicker", "static_lab"]

    [[scenarios]]                      # or entries as tables (a scenario may appear several times)
    name = "tunnel_exit"               # a preset or a scenario .toml file (relative to this file)
    params = { transition_ms = [15, 40, 150] }          # a grid: every combination
    zip = { step_db = [60, 90], exit_s = [0.8, 1.0] }   # lists taken in lockstep (equal lengths)
    sim = { "dvs.max_event_rate" = [12e6, "none"] }     # replaces the top-level sim for its keys
    duration_s = 1.0                                    # overrides the top-level duration_s

Inside ``params``, ``zip`` and ``sim`` a list is the values to sweep and anything else one fixed
value (a list-valued parameter such as ``static_lab``'s ``steps`` is written as a list of lists).
In ``sim`` and scenario ``params`` the string ``"none"`` stands for no value (TOML has no null),
e.g. ``dvs.max_event_rate = "none"``: no bandwidth ceiling. Controller entries take ``params``
and ``zip`` the same way (``{ name = "navid", params = { target_msv = [2.5, 3.0] } }``).

**Run spec and hash.** Every run is the plain dict :func:`necviz.runs.run_spec` takes, with one
controller. Its key is the first 16 hex digits of SHA-256 over its canonical JSON (sorted keys, no
spaces, whole floats written as integers so ``110`` and ``110.0`` agree, empty parameter tables
dropped) with every file it names (a scenario file, a profile) replaced by its base name and the
SHA-256 of its content: moving the sweep changes no hash, editing a scenario file changes them.
Identical runs listed twice collapse into one.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from necviz.core.errors import NecvizError, ParameterError

#: The version of the row/hash layout; part of every hash.
HASH_VERSION = 1
HASH_CHARS = 16
TOP_KEYS = {
    "name",
    "description",
    "seeds",
    "duration_s",
    "sift",
    "markers",
    "metrics",
    "profiles",
    "sim",
    "controllers",
    "scenarios",
}
SCENARIO_KEYS = {"name", "params", "zip", "sim", "duration_s"}
CONTROLLER_KEYS = {"name", "params", "zip"}
#: Most runs one sweep file may expand to. Planning holds every run (its spec, hash and columns:
#: about 1.4 kB each), so the grid is counted before anything is built and a larger one refused.
MAX_RUNS = 100_000
#: Most seeds of a sweep file (as ``compare --seeds``).
MAX_SEEDS = 10_000
BYTES_PER_RUN = 1400


class SweepFileError(ParameterError):
    """A sweep file is unreadable or a key in it is wrong (the message names the file and the key)."""


@dataclass
class Run:
    """One run of the grid: its hash, the spec for :func:`necviz.runs.run_spec` and the row's columns."""

    hash: str
    spec: dict
    columns: dict = field(default_factory=dict)


@dataclass
class Plan:
    """An expanded sweep file."""

    source: str
    text: str
    data: dict
    runs: list[Run]
    seeds: list[int]
    metrics: list[str] | None
    sift: bool
    duplicates: int = 0
    name: str = ""
    markers: bool = False

    @property
    def hashes(self) -> list[str]:
        return [r.hash for r in self.runs]

    @property
    def controllers(self) -> list[str]:
        return sorted({r.spec["controllers"][0] for r in self.runs})

    def cells(self) -> int:
        return len({cell_key(r.spec) for r in self.runs})

    def counts(self) -> dict:
        scen = sorted({r.columns["scenario"] for r in self.runs})
        return {
            "runs": len(self.runs),
            "cells": self.cells(),
            "seeds": len(self.seeds),
            "scenarios": len(scen),
            "controller_configurations": len(
                {json.dumps([r.spec["controllers"], r.spec["controller_params"]], sort_keys=True) for r in self.runs}
            ),
            "duplicates_dropped": self.duplicates,
        }


# -- small parsers ---------------------------------------------------------------------------------
def parse_seeds(value, where: str = "seeds") -> list[int]:
    """``"0..9"`` (inclusive), ``"1,5,9"`` or a list of integers -> sorted distinct seeds."""
    msg = f'{where} must be "a..b", "a,b,c" or a list of whole numbers >= 0, got {value!r}'
    too_many = f"{where}: {value!r} lists more than {MAX_SEEDS:,} seeds"
    if isinstance(value, list):
        items = value
    elif isinstance(value, str):
        s = value.strip()
        try:
            if ".." in s:
                a, b = s.split("..", 1)
                lo, hi = int(a), int(b)
                if hi - lo + 1 > MAX_SEEDS:  # counted before the list is made ("0..4294967295")
                    raise SweepFileError(too_many)
                items = list(range(lo, hi + 1)) if hi >= lo else None
            else:
                if s.count(",") >= MAX_SEEDS:
                    raise SweepFileError(too_many)
                items = [int(v) for v in s.split(",") if v.strip()]
        except SweepFileError:
            raise
        except ValueError:
            raise SweepFileError(msg) from None
        if items is None:
            raise SweepFileError(f"{where}: {value!r} ends before it starts")
    else:
        raise SweepFileError(msg)
    if len(items) > MAX_SEEDS:
        raise SweepFileError(f"{where}: {len(items):,} seeds; at most {MAX_SEEDS:,}")
    if not items or any(isinstance(v, bool) or not isinstance(v, int) or not 0 <= v < 2**32 for v in items):
        raise SweepFileError(msg)
    if len(set(items)) != len(items):
        raise SweepFileError(f"{where}: a seed appears twice in {value!r}")
    return sorted(items)


def _none(v):
    return None if isinstance(v, str) and v.strip().lower() == "none" else v


def _axis_values(table, where: str, none_words: bool) -> dict[str, list]:
    """``{key: value-or-list}`` -> ``{key: [values]}`` (a list is the values to sweep)."""
    if not isinstance(table, dict):
        raise SweepFileError(f"{where} must be a table of key = value(s), got {table!r}")
    out = {}
    for k, v in table.items():
        values = v if isinstance(v, list) else [v]
        if not values:
            raise SweepFileError(f"{where}.{k}: an empty list sweeps nothing")
        if any(isinstance(x, dict) for x in values):
            raise SweepFileError(f"{where}.{k}: values must be numbers, strings, booleans or lists, not tables")
        out[str(k)] = [_none(x) for x in values] if none_words else list(values)
    return out


def _count(params, zipped, where: str) -> int:
    """How many combinations :func:`_combinations` would make (without making them)."""
    grid = _axis_values(params if params is not None else {}, f"{where}.params", False)
    zips = _axis_values(zipped if zipped is not None else {}, f"{where}.zip", False)
    n = 1
    for v in grid.values():
        n *= len(v)
    return n * (min(len(v) for v in zips.values()) if zips else 1)


def _combinations(params, zipped, where: str, none_words: bool = False) -> list[dict]:
    """Every combination of a ``params`` grid and a ``zip`` table (product of grid and lockstep lists)."""
    grid = _axis_values(params if params is not None else {}, f"{where}.params", none_words)
    zips = _axis_values(zipped if zipped is not None else {}, f"{where}.zip", none_words)
    both = sorted(set(grid) & set(zips))
    if both:
        raise SweepFileError(f"{where}: {', '.join(both)} appears in both params and zip")
    if zips and len({len(v) for v in zips.values()}) > 1:
        lens = ", ".join(f"{k} has {len(v)}" for k, v in zips.items())
        raise SweepFileError(f"{where}.zip: lists must have equal lengths ({lens})")
    zip_rows = [dict(zip(zips, vals, strict=True)) for vals in zip(*zips.values(), strict=True)] if zips else [{}]
    grid_rows = [dict(zip(grid, vals, strict=True)) for vals in itertools.product(*grid.values())] if grid else [{}]
    return [{**g, **z} for g in grid_rows for z in zip_rows]


# -- hashing ---------------------------------------------------------------------------------------
def _canonical(v):
    if isinstance(v, bool) or v is None or isinstance(v, (int, str)):
        return v
    if isinstance(v, float):
        if not math.isfinite(v):
            return repr(v)
        return int(v) if v.is_integer() and abs(v) < 2**53 else v
    if isinstance(v, dict):
        return {str(k): _canonical(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_canonical(x) for x in v]
    raise SweepFileError(f"cannot hash a value of type {type(v).__name__}: {v!r}")


def _file_ref(path) -> dict:
    p = Path(path)
    try:
        digest = hashlib.sha256(p.read_bytes()).hexdigest()
    except OSError as e:
        raise SweepFileError(f"cannot read {p}: {e.strerror or e}") from None
    return {"file": p.name, "sha256": digest}


def spec_hash(spec: dict, files: dict | None = None) -> str:
    """The run's key: SHA-256 of its canonical JSON (see the module docstring), first 16 hex digits.

    ``files`` maps a spec key whose value is a path (``scenario``, ``profile``) to that file's
    :func:`_file_ref`; without it the references are computed here.
    """
    d = dict(spec)
    d["controller_params"] = {k: v for k, v in (d.get("controller_params") or {}).items() if v}
    for key in ("scenario", "profile"):
        v = d.get(key)
        if isinstance(v, str) and is_file_ref(key, v):
            d[key] = (files or {}).get(key) or _file_ref(v)
    text = json.dumps({"v": HASH_VERSION, "spec": _canonical(d)}, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:HASH_CHARS]


def is_file_ref(key: str, value: str) -> bool:
    if key == "profile":
        return True
    return value.endswith(".toml") or "/" in value or "\\" in value


def cell_key(spec: dict) -> str:
    """What identifies a cell: the spec without its seed (canonical JSON)."""
    d = {k: v for k, v in spec.items() if k != "seed"}
    d["controller_params"] = {k: v for k, v in (d.get("controller_params") or {}).items() if v}
    return json.dumps(_canonical(d), sort_keys=True, separators=(",", ":"))


# -- columns ---------------------------------------------------------------------------------------
def _scalar(v):
    """A value as a column entry: scalars as they are, lists and tables as JSON text."""
    if v is None or isinstance(v, (bool, int, float, str)):
        return v
    return json.dumps(v, sort_keys=True)


def spec_columns(spec: dict, scenario_label: str, profile_label: str | None) -> dict:
    """The row's description of a spec: flat columns, nested values as JSON text."""
    (ctrl,) = spec["controllers"]
    cols = {
        "scenario": scenario_label,
        "seed": spec["seed"],
        "duration_s": spec.get("duration_s"),
        "controller": ctrl,
        "profile": profile_label,
        "sift": bool(spec.get("sift", False)),
    }
    if spec.get("markers"):  # only when on: the specs (and hashes) of sweeps without it stay as they were
        cols["markers"] = True
    for k, v in sorted((spec.get("scenario_params") or {}).items()):
        cols[f"scenario_params.{k}"] = _scalar(v)
    for k, v in sorted(((spec.get("controller_params") or {}).get(ctrl) or {}).items()):
        cols[f"controller_params.{k}"] = _scalar(v)
    for k, v in sorted((spec.get("sim") or {}).items()):
        cols[f"sim.{k}"] = _scalar(v)
    return cols


# -- reading a sweep file --------------------------------------------------------------------------
def _entry(item, where: str, what: str, keys: set) -> dict:
    """A ``controllers`` / ``scenarios`` entry as a table: a bare name becomes ``{name = …}``; anything
    else but a table, or a key outside ``keys``, is a one-line error naming ``where``."""
    if isinstance(item, str):
        item = {"name": item}
    if not isinstance(item, dict):
        fields = ", ".join(k for k in ("name", "params", "zip", "sim") if k in keys)
        raise SweepFileError(f"{where} must be a {what} name or a table with {fields}; got {item!r}")
    bad = sorted(set(item) - keys)
    if bad:
        raise SweepFileError(f"{where}: unknown key(s) {', '.join(bad)}; accepted: {', '.join(sorted(keys))}")
    return item


def load_plan(path, *, check: bool = True) -> Plan:
    """Read, check and expand a sweep file (see the module docstring)."""
    p = Path(path)
    src = str(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise SweepFileError(f"sweep file {src} does not exist") from None
    except IsADirectoryError:
        raise SweepFileError(f"sweep file {src} is a folder") from None
    except (OSError, UnicodeDecodeError) as e:
        raise SweepFileError(f"cannot read sweep file {src}: {getattr(e, 'strerror', None) or e}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise SweepFileError(f"{src}: invalid TOML: {e}") from None
    try:
        return expand(data, base=p.parent, source=src, text=text, check=check)
    except SweepFileError as e:
        raise SweepFileError(f"{src}: {e}") from None
    except NecvizError as e:
        raise SweepFileError(f"{src}: {' '.join(str(e).split())}") from None


def _list_of(data, key, default=None):
    v = data.get(key, default)
    if v is None:
        return None
    if not isinstance(v, list):
        v = [v]
    if not v:
        raise SweepFileError(f"{key}: an empty list")
    return v


def expand(data: dict, base: Path = Path("."), source: str = "sweep", text: str = "", check: bool = True) -> Plan:
    """Expand parsed TOML into a :class:`Plan` (``base``: the folder relative file names start from)."""
    import necviz.tuned  # noqa: F401 - the tuned controllers are registered names too
    from necviz.core.control import CONTROLLERS
    from necviz.drivers.sim.scenes import SCENARIOS

    unknown = sorted(set(data) - TOP_KEYS)
    if unknown:
        raise SweepFileError(f"unknown key(s) {', '.join(unknown)}; accepted: {', '.join(sorted(TOP_KEYS))}")
    for key in ("scenarios", "controllers", "seeds"):
        if key not in data:
            raise SweepFileError(f"missing key {key!r}")
    seeds = parse_seeds(data["seeds"])
    duration = _duration(data.get("duration_s"), "duration_s")
    sift = data.get("sift", False)
    if not isinstance(sift, bool):
        raise SweepFileError(f"sift must be true or false, got {sift!r}")
    markers = data.get("markers", False)
    if not isinstance(markers, bool):
        raise SweepFileError(f"markers must be true or false, got {markers!r}")
    metrics = _list_of(data, "metrics")
    if metrics is not None and not all(isinstance(m, str) and m for m in metrics):
        raise SweepFileError(f"metrics must be a list of metric names, got {data['metrics']!r}")
    for key in ("name", "description"):
        if key in data and not isinstance(data[key], str):
            raise SweepFileError(f"{key} must be a string, got {data[key]!r}")

    # camera profiles
    profiles = []  # (spec value, label, loaded profile or None)
    for i, prof in enumerate(_list_of(data, "profiles", ["default"])):
        where = f"profiles[{i}]"
        if prof == "default":
            profiles.append((None, "default", None))
        elif isinstance(prof, str):
            path = (base / prof).resolve()
            from necviz.profiles import load_profile

            try:
                loaded = load_profile(path) if check else None
            except NecvizError as e:
                raise SweepFileError(f"{where}: {' '.join(str(e).split())}") from None
            profiles.append((str(path), prof, loaded))
        elif isinstance(prof, dict):
            from necviz.core.camera_profile import CameraProfile

            profiles.append(
                (prof, json.dumps(prof, sort_keys=True), CameraProfile.from_dict(prof, where) if check else None)
            )  # errors name `where`
        else:
            raise SweepFileError(f'{where} must be "default", a profile file or a profile table, got {prof!r}')

    # simulator overrides (grid)
    top_sim = _axis_values(data.get("sim", {}), "sim", none_words=True)
    _check_size(data, seeds, len(profiles), top_sim)

    # controllers
    ctrl_entries = []  # (name, params dict)
    for i, c in enumerate(_list_of(data, "controllers")):
        where = f"controllers[{i}]"
        c = _entry(c, where, "controller", CONTROLLER_KEYS)
        name = c.get("name")
        kind, _, label = str(name).partition("@")
        if kind not in CONTROLLERS or ("@" in str(name) and not label.replace("-", "_").isidentifier()):
            raise SweepFileError(
                f"{where}.name: unknown controller {name!r}; available: {', '.join(sorted(CONTROLLERS))} "
                "(a labelled variant: KIND@LABEL)"
            )
        for combo in _combinations(c.get("params"), c.get("zip"), where):
            ctrl_entries.append((name, combo, where))

    # scenarios
    scen_entries = []  # (spec scenario value, label, preset name, params, sim, duration)
    for i, s in enumerate(_list_of(data, "scenarios")):
        where = f"scenarios[{i}]"
        s = _entry(s, where, "scenario", SCENARIO_KEYS)
        name = s.get("name")
        if not isinstance(name, str) or not name:
            raise SweepFileError(f"{where}.name: a preset ({', '.join(sorted(SCENARIOS))}) or a scenario file")
        if name in SCENARIOS:
            value, preset = name, name
        elif is_file_ref("scenario", name):
            path = (base / name).resolve()
            if not path.is_file():
                raise SweepFileError(f"{where}.name: scenario file {name!r} does not exist")
            from necviz.drivers.sim.scenes import load_scenario_spec

            try:
                value, preset = str(path), load_scenario_spec(path)["name"]
            except NecvizError as e:
                raise SweepFileError(f"{where}.name: {' '.join(str(e).split())}") from None
        else:
            raise SweepFileError(
                f"{where}.name: {name!r} is neither a preset ({', '.join(sorted(SCENARIOS))}) nor a .toml scenario file"
            )
        dur = _duration(s["duration_s"], f"{where}.duration_s") if "duration_s" in s else duration
        sim = {**top_sim, **_axis_values(s.get("sim", {}), f"{where}.sim", none_words=True)}
        sim_rows = [dict(zip(sim, vals, strict=True)) for vals in itertools.product(*sim.values())] if sim else [{}]
        combos = _combinations(s.get("params"), s.get("zip"), where, none_words=True)
        if check:
            _check_scenario_params(preset, combos, where)
        for params in combos:
            for sim_row in sim_rows:
                scen_entries.append((value, name, params, sim_row, dur))

    if check:
        _check_sims({json.dumps(r, sort_keys=True): r for _, _, _, r, _ in scen_entries}.values())
        _check_controllers(ctrl_entries, [p for _, _, p in profiles])

    n = len(scen_entries) * len(profiles) * len(ctrl_entries) * len(seeds)
    if n > MAX_RUNS:
        raise SweepFileError(f"the grid has {n:,} runs; at most {MAX_RUNS:,} per sweep file")
    runs, seen, dup = [], set(), 0
    file_refs: dict = {}
    for value, label, params, sim_row, dur in scen_entries:
        for prof_value, prof_label, _ in profiles:
            for ctrl, cparams, _ in ctrl_entries:
                for seed in seeds:
                    spec = {
                        "scenario": value,
                        "seed": seed,
                        "duration_s": dur,
                        "scenario_params": dict(params),
                        "controllers": [ctrl],
                        "controller_params": {ctrl: dict(cparams)} if cparams else {},
                        "profile": prof_value,
                        "sim": dict(sim_row),
                        "sift": sift,
                    }
                    if markers:  # only when on, so sweeps without markers keep their hashes
                        spec["markers"] = True
                    refs = {}
                    for key in ("scenario", "profile"):
                        v = spec[key]
                        if isinstance(v, str) and is_file_ref(key, v):
                            if v not in file_refs:
                                file_refs[v] = _file_ref(v)
                            refs[key] = file_refs[v]
                    h = spec_hash(spec, refs)
                    if h in seen:
                        dup += 1
                        continue
                    seen.add(h)
                    runs.append(Run(h, spec, spec_columns(spec, label, prof_label)))
    return Plan(source, text, data, runs, seeds, metrics, sift, dup, data.get("name", Path(source).stem), markers)


def _check_size(data: dict, seeds: list, profiles: int, top_sim: dict) -> None:
    """Refuse a grid of more than :data:`MAX_RUNS` runs from its counts, before any run is built."""
    ctrl = 0
    for i, c in enumerate(_list_of(data, "controllers")):
        if isinstance(c, dict):
            ctrl += _count(c.get("params"), c.get("zip"), f"controllers[{i}]")
        else:
            ctrl += 1
    scen = 0
    for i, sc in enumerate(_list_of(data, "scenarios")):
        if isinstance(sc, dict):
            sim = {**top_sim, **_axis_values(sc.get("sim", {}), f"scenarios[{i}].sim", none_words=True)}
            rows = 1
            for v in sim.values():
                rows *= len(v)
            scen += _count(sc.get("params"), sc.get("zip"), f"scenarios[{i}]") * rows
        else:
            rows = 1
            for v in top_sim.values():
                rows *= len(v)
            scen += rows
    n = scen * profiles * ctrl * len(seeds)
    if n > MAX_RUNS:
        raise SweepFileError(
            f"the grid has {n:,} runs ({scen:,} scenario configurations x {profiles} profile(s) x {ctrl:,} "
            f"controller configurations x {len(seeds):,} seeds; planning them would take about "
            f"{n * BYTES_PER_RUN / 2**30:,.1f} GB); at most {MAX_RUNS:,} per sweep file: split it into several"
        )


def _duration(v, where):
    if v is None:
        return None
    from necviz.core.checks import check_number

    try:
        from necviz.core.limits import MAX_DURATION_S

        return check_number(where, v, 0.0, MAX_DURATION_S, lo_open=True)
    except ParameterError as e:
        raise SweepFileError(str(e)) from None


def _check_scenario_params(preset: str, combos: list[dict], where: str) -> None:
    """Names and ranges of scenario parameters (as the preset checks them), before anything runs."""
    from necviz.core.checks import check_number
    from necviz.drivers.sim.scenes import scenario_params

    known = scenario_params(preset)
    for combo in combos:
        for k, v in combo.items():
            if k not in known:
                raise SweepFileError(
                    f"{where}.params.{k}: {preset} has no parameter {k!r}; accepted: {', '.join(known)}"
                )
            spec = known[k]
            if spec.kind == "float" or (spec.kind == "opt_float" and v is not None):
                try:
                    check_number(k, v, spec.lo, spec.hi, where=preset)
                except ParameterError as e:
                    raise SweepFileError(f"{where}.params.{k}: {e}") from None


def _check_sims(rows) -> None:
    from necviz.runs import sim_models

    for row in rows:
        try:
            sim_models(row)
        except (NecvizError, TypeError, ValueError) as e:
            raise SweepFileError(f"sim: {' '.join(str(e).split())}") from None


def _check_controllers(entries, profiles) -> None:
    """Build every controller configuration once (cheap) so a bad parameter is refused up front."""
    from necviz.core.control import CameraLimits
    from necviz.core.sensor import DAVIS346
    from necviz.drivers.sim.aps import ApsParams
    from necviz.runs import build_controller

    aps = ApsParams()
    limits = CameraLimits(aps.exposure_min_us, aps.exposure_max_us, aps.gain_max)
    seen = set()
    for name, params, where in entries:
        key = json.dumps([name, params], sort_keys=True, default=str)
        if key in seen:
            continue
        seen.add(key)
        for prof in profiles[:1] or [None]:
            try:
                build_controller(name, params, sensor=DAVIS346, limits=limits, exposure_us=5_000.0, profile=prof)
            except (NecvizError, TypeError, ValueError) as e:
                raise SweepFileError(f"{where}.params: {' '.join(str(e).split())}") from None


__all__ = [
    "HASH_VERSION",
    "Plan",
    "Run",
    "SweepFileError",
    "cell_key",
    "expand",
    "load_plan",
    "parse_seeds",
    "spec_columns",
    "spec_hash",
]
