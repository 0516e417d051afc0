#!/usr/bin/env python
"""The paper's Table 1 on this machine; same as `necviz bench estimators`, writing
benchmarks/results/estimators.json unless --json says otherwise.

usage: python benchmarks/estimators.py [necviz bench estimators options]
"""

import sys
from pathlib import Path

from necviz.commands.cli import main

if __name__ == "__main__":
    args = sys.argv[1:]
    if "--json" not in args:
        args += ["--json", str(Path(__file__).parent / "results" / "estimators.json")]
    sys.exit(main(["bench", "estimators", *args]))
