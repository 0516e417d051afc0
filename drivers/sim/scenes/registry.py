"""The registry of scenario presets: build one by name, list its parameters, render them as Markdown."""

from __future__ import annotations

from collections.abc import Callable

from necviz.core.checks import format_number
from necviz.core.errors import ParameterError
from necviz.core.sensor import DAVIS346, SensorGeometry
from necviz.drivers.sim.scene import Scene
from necviz.drivers.sim.scenes.flicker import Flicker
from necviz.drivers.sim.scenes.handheld_scan import HandheldScan
from necviz.drivers.sim.scenes.indoor_outdoor import IndoorOutdoor
from necviz.drivers.sim.scenes.preset import US, Param, params_markdown, summary
from necviz.drivers.sim.scenes.static_lab import StaticLab
from necviz.drivers.sim.scenes.tunnel_exit import TunnelExit

__all__ = ["SCENARIOS", "make_scenario", "scenario_params", "scenario_params_markdown"]

SCENARIOS: dict[str, Callable[..., Scene]] = {
    "tunnel_exit": TunnelExit,
    "indoor_outdoor": IndoorOutdoor,
    "flicker": Flicker,
    "static_lab": StaticLab,
    "handheld_scan": HandheldScan,
}


def scenario_params(name: str) -> dict[str, Param]:
    """The documented parameters (default, range, meaning) of a preset."""
    if name not in SCENARIOS:
        raise ParameterError(f"unknown scenario {name!r}; known: {', '.join(sorted(SCENARIOS))}")
    return dict(SCENARIOS[name].PARAMS)


def make_scenario(
    name: str, sensor: SensorGeometry = DAVIS346, duration_us: int | None = None, seed: int = 0, **params
) -> Scene:
    """Build the named preset; ``duration_us`` None uses the preset's default duration."""
    if not isinstance(name, str) or name not in SCENARIOS:
        raise ParameterError(f"unknown scenario {name!r}; known: {', '.join(sorted(SCENARIOS))}")
    return SCENARIOS[name](sensor=sensor, duration_us=duration_us, seed=seed, **params)


def scenario_params_markdown() -> str:
    """Every preset's parameter table as Markdown (``docs/simulator.md``, "Preset parameters")."""
    out = [
        "Generated from each preset's `PARAMS` by `necviz.drivers.sim.scenes.scenario_params_markdown()`. "
        "Pass parameters as `make_scenario(name, seed=..., duration_us=..., **params)` or in the `[params]` "
        "table of a scenario TOML file; a value outside its range is refused with a one-line error."
    ]
    for name, cls in SCENARIOS.items():
        out += [
            "",
            f"#### `{name}`",
            "",
            f"{summary(cls)} Default duration {format_number(cls.DEFAULT_DURATION_US / US)} s.",
            "",
            params_markdown(cls.PARAMS),
        ]
    return "\n".join(out) + "\n"
