"""What every benchmark shares: a description of the machine and writing its JSON."""

from __future__ import annotations

import json
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
    path = Path(json_path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result, indent=2) + "\n")
    if out is not None:
        print(f"wrote {json_path}", file=out)
