"""The README stays short and true: every command in its code blocks runs on a fresh clone with no data,
and the measured-results page and the README's results block are what the results files say."""

from __future__ import annotations

import importlib.util
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # closed loops, subprocesses or Dask: `pytest -m 'not slow'` leaves them out

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"


def bash_commands() -> list[str]:
    """The command lines of the README's ``bash`` blocks (comments stripped), in order."""
    text = README.read_text(encoding="utf-8")
    out = []
    for block in re.findall(r"```bash\n(.*?)```", text, re.S):
        for line in block.splitlines():
            line = line.split(" #", 1)[0].strip()
            if line and not line.startswith("#"):
                out.append(line)
    return out


def test_the_readme_is_one_screen_of_what_a_user_needs():
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= 250
    text = "\n".join(lines)
    for word in ("this session", "issue ", "release before"):
        assert word not in text.lower(), f"the README talks about the project's process: {word!r}"


def test_every_readme_command_runs_in_a_fresh_folder_with_no_data(tmp_path):
    cmds = bash_commands()
    assert any(c.startswith("necviz demo") for c in cmds) and any(c.startswith("necviz replay") for c in cmds)
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    bindir = Path(sys.executable).parent
    env["PATH"] = f"{bindir}{os.pathsep}{env.get('PATH', '')}"
    for cmd in cmds:
        argv = shlex.split(cmd)
        if argv[0] in ("pip", "pytest"):  # the install and the suite itself: what .ci/run does
            continue
        assert argv[0] == "necviz", cmd
        if argv[1] == "demo" and "--duration" not in argv:
            argv += ["--duration", "0.5"]  # the same command, shorter: the suite's time budget
        if argv[1] == "live" and "--duration" in argv:
            argv[argv.index("--duration") + 1] = "1"
        out = subprocess.run(
            argv + ["--no-prompt"] * (argv[1] in ("demo", "live")),
            cwd=tmp_path,
            env=env,
            capture_output=True,
            text=True,
            timeout=600,
        )
        assert out.returncode == 0, f"{cmd}: {out.stderr[-2000:]}"


def test_the_results_page_and_the_readme_block_are_generated_from_the_results_files():
    spec = importlib.util.spec_from_file_location("results_page", ROOT / "benchmarks" / "results_page.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    results = mod.load()
    assert (ROOT / "docs" / "results.md").read_text(encoding="utf-8") == mod.render_page(results), (
        "docs/results.md is out of date: run python benchmarks/results_page.py"
    )
    readme = README.read_text(encoding="utf-8")
    assert readme == mod.readme_with(readme, mod.render_headline(results))
    for name in results:  # every results file has a section that names its command
        assert "Command: `(not recorded)`" not in mod.render_page({name: results[name]}), name
