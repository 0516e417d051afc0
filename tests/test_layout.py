"""The package's layers: one name per module, imports without circles, the top-level folders importable one way."""

from __future__ import annotations

import ast
import subprocess
import sys
from collections import Counter
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = {"necviz": "necviz", "core": "necviz.core", "drivers": "necviz.drivers", "layouts": "necviz.layouts"}


def _modules() -> dict[str, Path]:
    out = {}
    for folder, pkg in PACKAGES.items():
        for path in (ROOT / folder).rglob("*.py"):
            rel = path.relative_to(ROOT / folder).with_suffix("").parts
            if rel[-1] == "__init__":
                rel = rel[:-1]
            out[".".join((pkg, *rel))] = path
    return out


def _imports(path: Path, modules: dict[str, Path]) -> set[str]:
    """The package modules ``path`` imports (at any depth of the file), by absolute name."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            for a in node.names:
                sub = f"{node.module}.{a.name}"
                found.add(sub if sub in modules else node.module)
        elif isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
    return {m for m in found if m in modules}


def test_no_two_modules_share_a_name():
    """A module's name (file or package folder) is used once across the tree (``replay.py`` beside a
    ``replay/`` package is the confusion this prevents)."""
    names = Counter(
        p.parent.name if p.name == "__init__.py" else p.stem
        for m, p in _modules().items()
        if p.name != "__main__.py" and m not in PACKAGES.values()
    )
    assert [n for n, k in names.items() if k > 1] == []


def test_the_import_graph_has_no_circles():
    modules = _modules()
    graph = {m: _imports(p, modules) - {m} for m, p in modules.items()}
    # a package's __init__ importing its own submodules is how packages re-export; only module-to-module edges count
    graph = {
        m: {d for d in deps if not (modules[d].name == "__init__.py" and m.startswith(d + "."))}
        for m, deps in graph.items()
    }
    state: dict[str, int] = {}
    cycles = []

    def visit(m, stack):
        state[m] = 1
        stack.append(m)
        for d in sorted(graph[m]):
            if modules[m].name == "__init__.py" and d.startswith(m + "."):
                continue
            if state.get(d) == 1:
                cycles.append(stack[stack.index(d) :] + [d])
            elif d not in state:
                visit(d, stack)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m, [])
    assert cycles == []


def test_core_does_no_io_and_needs_no_opencv():
    # the two image-gradient baselines (Shim, Bégin) are defined by OpenCV's Sobel and Farneback flow
    for path in (p for p in (ROOT / "core").rglob("*.py") if p.name not in ("shim.py", "begin.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                assert not any(a.name in ("cv2", "json", "pathlib") for a in node.names), path
            if isinstance(node, ast.ImportFrom):
                assert node.module not in ("cv2", "pathlib", "json"), path
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
                assert node.func.id != "open", f"{path}:{node.lineno} opens a file"


@pytest.mark.parametrize("folder", ["core", "drivers", "layouts"])
def test_top_level_folders_refuse_to_import_as_packages(folder):
    code = f"import sys; sys.path.insert(0, {str(ROOT)!r}); import {folder}"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=str(ROOT))
    assert out.returncode != 0
    assert f"import necviz.{folder}" in out.stderr.strip().splitlines()[-1]
