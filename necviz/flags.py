"""The command line's flags: every numeric rule in one table, and which option field each flag sets.

Kept in a module of its own that imports nothing heavy, so the parser (``necviz --help``, a
mistyped flag) can use it without loading NumPy; :mod:`necviz.options` checks the option objects
against the same table (:func:`check_field`), and refuses a value with an
:class:`~necviz.core.errors.OptionError` naming the field (``ClipOptions.before_s``). The command line
shows the flag instead (:data:`FIELD_FLAGS`, :func:`in_flag_terms`): the one place fields map to flags.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from necviz.core.errors import OptionError, ParameterError
from necviz.core.limits import MAX_DURATION_S, MAX_SEED


@dataclass(frozen=True)
class NumberRule:
    """What a numeric flag accepts: ``[lo, hi]`` (``lo_open``: ``lo`` itself excluded), a whole
    number if ``integer``. NaN, infinities and text that is not a number are always refused."""

    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    integer: bool = False


#: Every numeric flag of the command line (and the option objects behind it). A key is the flag, or
#: ``"COMMAND --flag"`` where a command gives it another range. The parser's types (:func:`number`)
#: and the option objects (:func:`check_flag`) both read this table.
NUMBER_FLAGS: dict[str, NumberRule] = {
    "--seed": NumberRule(0, MAX_SEED, integer=True),
    "--duration": NumberRule(0.0, MAX_DURATION_S, lo_open=True),  # a simulated scene (as in scenario files)
    "live --duration": NumberRule(0.0, 24 * 3600.0, lo_open=True),  # a camera session
    "--seeds": NumberRule(1, 10_000, integer=True),
    "--event-window-ms": NumberRule(0.1, 10_000.0),
    "--event-points": NumberRule(0, 10_000_000, integer=True),
    "--image-rate": NumberRule(0.0, 1000.0, lo_open=True),
    "--start": NumberRule(0.0, 1e9),
    "--end": NumberRule(0.0, 1e9, lo_open=True),
    "--exposure-us": NumberRule(0.0, 1e8, lo_open=True),
    "--emulate-unplug": NumberRule(0.0, 24 * 3600.0, lo_open=True),
    "--pipe-timeout": NumberRule(0.0, 24 * 3600.0, lo_open=True),
    "--grpc-port": NumberRule(1, 65535, integer=True),
    "--web-port": NumberRule(1, 65535, integer=True),
    "--speed": NumberRule(1e-3, 1e4),
    # benchmarks
    "bench --events": NumberRule(1, 1_000_000_000, integer=True),
    "bench --duration": NumberRule(0.0, 600.0, lo_open=True),
    "bench --fps": NumberRule(1.0, 200.0),
    "bench --exposure-us": NumberRule(1, 1_000_000, integer=True),
    "bench --repeats": NumberRule(1, 100, integer=True),
    "bench --edi-samples": NumberRule(1, 4096, integer=True),
    "bench --cameras": NumberRule(1, 32, integer=True),
    "bench --seconds": NumberRule(0.0, 600.0, lo_open=True),
    "bench --rate": NumberRule(0.0, 50.0, lo_open=True),
    "bench --batch-us": NumberRule(1, 1_000_000, integer=True),
    # the flight recorder and videos
    "--clip-before": NumberRule(0.0, 600.0),
    "--clip-after": NumberRule(0.0, 600.0),
    "--clip-memory": NumberRule(1.0, float(1 << 20)),
    "--video-fps": NumberRule(1.0, 240.0),
    # calibration
    "calibrate --duration": NumberRule(0.0, 600.0, lo_open=True),
    "--min-change": NumberRule(0.0, 10.0),
    "--min-pixels": NumberRule(1, 1 << 22, integer=True),
    "--max-pixels": NumberRule(1, 1 << 22, integer=True),
    "--max-pairs": NumberRule(2, 1_000_000, integer=True),
    "--max-lag": NumberRule(1, 50, integer=True),
    "--max-event-rate": NumberRule(0.0, 1e4),
    "--slow-rate": NumberRule(0.0, 1e6, lo_open=True),
    # devices --check
    "devices --seconds": NumberRule(0.0, 60.0, lo_open=True),
    # sweeps
    "--workers": NumberRule(1, 1024, integer=True),
    "--retries": NumberRule(0, 100, integer=True),
}


#: The flag that sets each option field (``"Class.field"``): how the command line names a refused value.
#: :func:`check_field` also reads a numeric field's rule here (the flag's, in :data:`NUMBER_FLAGS`).
FIELD_FLAGS: dict[str, str] = {
    "SceneOptions.scenario": "--scenario",
    "SceneOptions.seed": "--seed",
    "SceneOptions.duration_s": "--duration",
    "SceneOptions.params": "--set",
    "ViewerOptions.layout": "--layout",
    "ViewerOptions.grpc_port": "--grpc-port",
    "ViewerOptions.web_port": "--web-port",
    "ViewerOptions.memory_limit": "--memory-limit",
    "ShowOptions.speed": "--speed",
    "ShowOptions.event_window_ms": "--event-window-ms",
    "ShowOptions.event_points": "--event-points",
    "ShowOptions.image_rate_hz": "--image-rate",
    "TuneOptions.file": "--tune-file",
    "TuneOptions.dvs": "--dvs",
    "ClipOptions.folder": "--clips",
    "ClipOptions.before_s": "--clip-before",
    "ClipOptions.after_s": "--clip-after",
    "ClipOptions.memory_mb": "--clip-memory",
    "VideoOptions.path": "--video",
    "VideoOptions.speed": "--speed",
    "VideoOptions.fps": "--video-fps",
    "DemoOptions.controllers": "--controllers",
    "ReplayOptions.file": "FILE",
    "ReplayOptions.controller": "--controller",
    "ReplayOptions.start_s": "--start",
    "ReplayOptions.end_s": "--end",
    "ReplayOptions.exposure_us": "--exposure-us",
    "ReplayOptions.pipe_timeout_s": "--pipe-timeout",
    "ExportOptions.file": "IN",
    "ExportOptions.out_path": "OUT",
    "ExportOptions.start_s": "--start",
    "ExportOptions.end_s": "--end",
    "ExportOptions.exposure_us": "--exposure-us",
    "ExportOptions.compression": "--compression",
    "ExportOptions.pipe_timeout_s": "--pipe-timeout",
    "LiveOptions.device": "--device",
    "LiveOptions.controller": "--controller",
    "LiveOptions.duration_s": "--duration",
    "LiveOptions.emulate_unplug_s": "--emulate-unplug",
    "LiveOptions.usb": "--usb",
    "LiveOptions.usb_transfers": "--usb-transfers",
    "CompareOptions.controllers": "--controllers",
    "CompareOptions.seeds": "--seeds",
    "CompareOptions.controller_params": "--param",
}


def check_field(field: str, value, command: str | None = None):
    """``value`` of the option field ``field`` (``"ClipOptions.before_s"``), checked against its flag's rule
    in :data:`NUMBER_FLAGS`; returns it as a float (an int for whole-number fields). Raises a one-line
    :class:`OptionError` naming the field."""
    from necviz.core.checks import parse_number

    r = _rule(FIELD_FLAGS[field], command)
    try:
        return parse_number(field, value, r.lo, r.hi, lo_open=r.lo_open, integer=r.integer)
    except OptionError:
        raise
    except ParameterError as e:
        raise OptionError(field, str(e)) from None


def in_flag_terms(error: BaseException) -> str:
    """The message of ``error`` as the command line shows it: every option field an :class:`OptionError`
    names replaced by its flag (:data:`FIELD_FLAGS`); any other error's message as it is."""
    text = str(error)
    if isinstance(error, OptionError):
        fields = sorted((f for f in FIELD_FLAGS if f in text), key=len, reverse=True)
        for f in fields:
            text = re.sub(rf"(?<![\w.]){re.escape(f)}(?!\w)", FIELD_FLAGS[f], text)
    return text


def _rule(flag: str, command: str | None) -> NumberRule:
    if command is not None and f"{command} {flag}" in NUMBER_FLAGS:
        return NUMBER_FLAGS[f"{command} {flag}"]
    return NUMBER_FLAGS[flag]


def check_flag(flag: str, value, command: str | None = None):
    """``value`` (a number, or text as typed) checked against :data:`NUMBER_FLAGS`; returns it as a
    float (an int for whole-number flags). Raises a one-line :class:`ParameterError`."""
    from necviz.core.checks import parse_number

    r = _rule(flag, command)
    return parse_number(flag, value, r.lo, r.hi, lo_open=r.lo_open, integer=r.integer)


def number(flag: str, command: str | None = None):
    """An ``argparse`` type for ``flag`` (:data:`NUMBER_FLAGS`): the checked number, or a one-line
    ``ArgumentTypeError``."""
    import argparse

    _rule(flag, command)  # a flag missing from the table is a bug, found when the parser is built

    def convert(text):
        try:
            return check_flag(flag, text, command)
        except ParameterError as e:
            raise argparse.ArgumentTypeError(str(e)) from None

    convert.__name__ = flag.lstrip("-").replace("-", "_")
    # lets tests find every numeric flag; mypy does not model attributes set on a function
    convert.necviz_rule = (flag, command)  # type: ignore[attr-defined]
    return convert


_MEMORY = re.compile(r"^\s*(\d+(?:\.\d*)?|\.\d+)\s*(%|b|kb|mb|gb|tb|kib|mib|gib|tib)?\s*$", re.IGNORECASE)


def parse_memory_limit(text, label: str = "--memory-limit") -> str:
    """A viewer memory limit as Rerun takes it (``1GB``, ``500MiB``, ``75%``), checked: a positive
    amount with a unit (B, kB, MB, GB, TB, KiB, MiB, GiB, TiB) or a percentage up to 100."""
    m = _MEMORY.match(str(text))
    value = float(m.group(1)) if m else 0.0
    unit = (m.group(2) or "B").lower() if m else ""
    if not m or not value > 0 or (unit == "%" and value > 100) or (unit == "b" and value < 1 << 20):
        raise ParameterError(f"{label} expects an amount like 1GB, 500MiB or 50% (at least 1 MB), got {text!r}")
    return str(text).strip().replace(" ", "")


__all__ = [
    "FIELD_FLAGS",
    "NUMBER_FLAGS",
    "NumberRule",
    "check_field",
    "check_flag",
    "in_flag_terms",
    "number",
    "parse_memory_limit",
]
