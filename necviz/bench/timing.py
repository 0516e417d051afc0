"""What every benchmark shares: a description of the machine and writing its JSON."""

from __future__ import annotations

import os
import platform
import statistics
import sys
from collections.abc import Callable
from pathlib import Path

import numba as nb
import numpy as np


def machine() -> dict:
    """Python, processor, core count, the numeric libraries the figures depend on, and the load average
    (1, 5, 15 min) when the figures were taken: the machine may be shared, so a figure without its load
    is not comparable."""
    return {
        "python": platform.python_version(),
        "processor": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "numba": nb.__version__,
        "numpy": np.__version__,
        "load_average": [round(v, 2) for v in os.getloadavg()] if hasattr(os, "getloadavg") else None,
    }


def spread(values) -> dict:
    """``{"median", "min", "max", "runs"}`` of repeated measurements (the figure and its spread)."""
    v = np.asarray(list(values), dtype=np.float64)
    return {"median": float(np.median(v)), "min": float(v.min()), "max": float(v.max()), "runs": int(v.size)}


def command_line(script: str, parser, args) -> str:
    """``python SCRIPT`` with every option of ``parser`` that ``args`` sets away from its default, in the
    parser's order (what a results file records as the command that made it; ``%g`` for floats)."""
    words = [f"python {script}"]
    for action in parser._actions:  # argparse's public API has no other way to list the options
        if not action.option_strings or action.dest == "help":
            continue
        value = getattr(args, action.dest, action.default)
        if value != action.default:
            words.append(
                f"{action.option_strings[-1]} {value:g}"
                if isinstance(value, float)
                else f"{action.option_strings[-1]} {value}"
            )
    return " ".join(words)


def median_table(
    walls: dict[str, list[float]],
    duration_s: float,
    label: str,
    base: str,
    last: tuple[str, Callable[[float, float], float]],
    out=sys.stdout,
) -> dict[str, float]:
    """Print the median wall time of each condition of an alternated run (``walls``: condition -> wall s of
    each run over ``duration_s`` of stream), as a real-time factor, and a last column ``last = (header,
    f(median, base's median))`` against condition ``base``; returns the medians."""
    med = {name: statistics.median(w) for name, w in walls.items()}
    width = max(len(label), *map(len, med))
    head, column = last
    print(f"\n  {label:{width}s} {'RT factor':>9s} {'wall s':>7s} {head:>{max(7, len(head))}s}", file=out)
    for name, w in med.items():
        print(
            f"  {name:{width}s} {duration_s / w:9.1f} {w:7.3f} {column(w, med[base]):{max(7, len(head))}.3f}", file=out
        )
    return med


def write_result(result: dict, json_path, out) -> None:
    """Write ``result`` as JSON to ``json_path`` (folders created) and say so; nothing if no path."""
    if not json_path:
        return
    from necviz.outputs import write_json

    path = Path(json_path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_json(path, result, indent=2, flag="--json")  # whole or not at all (a full disk leaves nothing)
    if out is not None:
        print(f"wrote {json_path}", file=out)
