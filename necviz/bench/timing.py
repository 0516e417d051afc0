"""What every benchmark shares: a description of the machine and writing its JSON."""

from __future__ import annotations

import os
import platform
from pathlib import Path

import numba as nb
import numpy as np


def machine() -> dict:
    """Python, processor, core count and the numeric libraries the figures depend on."""
    return {
        "python": platform.python_version(),
        "processor": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "numba": nb.__version__,
        "numpy": np.__version__,
    }


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
