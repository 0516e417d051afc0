"""The package and its docs stand on their own: no citation of the team's private notes, no broken links.

* Nothing under ``core/``, ``drivers/``, ``necviz/``, ``layouts/``, ``docs/``, ``examples/`` or in
  ``README.md`` mentions the private ``shared/reference`` folder or one of its note files by name
  (a user who clones or installs necviz does not have them). A name that is also a page of
  ``docs/`` (``docs/baselines.md``, ``docs/file-formats.md``) is fine when it points at that page.
* Every relative link in ``docs/*.md`` and ``README.md`` resolves to a file or folder inside the
  repository, and every ``#anchor`` into a Markdown file names one of its headings (GitHub's slug
  rule).
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
SCOPE = ("core", "drivers", "necviz", "layouts", "docs", "examples", "README.md")
NOTE_FILES = ("nec-method.md", "davis-usb.md", "baselines.md", "file-formats.md", "simulation.md", "rerun.md")
PRIVATE_FOLDER = "shared/reference"
_NOTE_RE = re.compile(r"[\w./-]*(?:" + "|".join(re.escape(n) for n in NOTE_FILES) + r")")
_LINK_RE = re.compile(r"\[[^\]\n]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
_SKIP_DIRS = {"__pycache__", ".pytest_cache"}


def scanned_files() -> list[Path]:
    out = []
    for name in SCOPE:
        p = ROOT / name
        if p.is_file():
            out.append(p)
        elif p.is_dir():
            out += [
                f
                for f in sorted(p.rglob("*"))
                if f.is_file() and not _SKIP_DIRS.intersection(f.relative_to(ROOT).parts)
            ]
    return out


def _is_docs_page(token: str, where: Path) -> bool:
    """``token`` (a path ending in a note's file name) names an existing page of ``docs/``."""
    for base in (where.parent, ROOT):
        target = (base / token).resolve()
        if target.is_file() and target.is_relative_to(DOCS):
            return True
    return False


def private_citations(text: str, where: Path) -> list[str]:
    """Mentions of the private folder or of a note file that is not a ``docs/`` page, one per hit."""
    hits = []
    for lineno, line in enumerate(text.splitlines(), 1):
        if PRIVATE_FOLDER in line:
            hits.append(f"{lineno}: {line.strip()}")
            continue
        for m in _NOTE_RE.finditer(line):
            token = m.group(0)
            if Path(token).name in NOTE_FILES and not _is_docs_page(token, where):
                hits.append(f"{lineno}: {line.strip()}")
                break
    return hits


def _unfenced(text: str) -> list[str]:
    """Lines of a Markdown text, blank inside fenced code blocks."""
    out, fenced = [], False
    for line in text.splitlines():
        if line.lstrip().startswith("```"):
            fenced = not fenced
            out.append("")
            continue
        out.append("" if fenced else line)
    return out


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces to hyphens."""
    h = re.sub(r"`", "", heading.strip().lower())
    h = re.sub(r"[^\w\- ]", "", h)
    return h.replace(" ", "-")


def anchors(md: Path) -> set[str]:
    seen: dict[str, int] = {}
    out = set()
    for line in _unfenced(md.read_text(encoding="utf-8")):
        m = re.match(r"^(#{1,6})\s+(.*?)\s*#*\s*$", line)
        if not m:
            continue
        s = slug(m.group(2))
        n = seen.get(s, 0)
        seen[s] = n + 1
        out.add(s if n == 0 else f"{s}-{n}")
    return out


def relative_links(md: Path) -> list[str]:
    links = []
    for line in _unfenced(md.read_text(encoding="utf-8")):
        for m in _LINK_RE.finditer(re.sub(r"`[^`]*`", "", line)):  # not inside inline code
            target = m.group(1)
            if not re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I):  # not http:, mailto:, ...
                links.append(target)
    return links


def broken_links(md: Path, root: Path = ROOT) -> list[str]:
    bad = []
    for target in relative_links(md):
        path, _, frag = target.partition("#")
        dest = (md.parent / path).resolve() if path else md
        if not dest.is_relative_to(root):
            bad.append(f"{target}: points outside the repository")
        elif not dest.exists():
            bad.append(f"{target}: no such file")
        elif frag and dest.suffix == ".md" and frag not in anchors(dest):
            bad.append(f"{target}: no heading #{frag} in {dest.relative_to(root)}")
    return bad


def link_sources() -> list[Path]:
    return [ROOT / "README.md", *sorted(DOCS.glob("*.md"))]


# -- the checker itself ------------------------------------------------------------------------------


def test_checker_flags_private_citations_and_accepts_docs_pages():
    here = ROOT / "core" / "x.py"
    assert private_citations("Facts from ``../shared/reference/davis-usb.md`` §2.", here)
    assert private_citations("see shared/reference for details", here)
    assert private_citations("sign per nec-method.md", here)
    assert private_citations("(baselines.md §2.3)", here)  # the note, not the docs page
    assert private_citations("layout: ../shared/reference/file-formats.md", here)
    assert not private_citations("summary in docs/baselines.md and docs/file-formats.md", here)
    assert not private_citations("see docs/method.md; simulation results", here)
    assert not private_citations("[file formats](file-formats.md)", DOCS / "README.md")


def test_checker_finds_broken_links(tmp_path):
    root = tmp_path.resolve()
    (root / "docs").mkdir()
    (root / "docs" / "a.md").write_text("# Title\n\n## The sign (Eq. 5)\n", encoding="utf-8")
    md = root / "docs" / "index.md"
    md.write_text(
        "[ok](a.md) [ok](a.md#the-sign-eq-5) [web](https://example.org/x.md) [self](#top)\n"
        "# Top\n```\n[not a link](nowhere.md)\n```\n`[code](nowhere.md)`\n",
        encoding="utf-8",
    )
    assert broken_links(md, root) == []
    md.write_text("[gone](b.md) [anchor](a.md#no-such) [out](../../x.md)\n", encoding="utf-8")
    assert [b.split(":")[0] for b in broken_links(md, root)] == ["b.md", "a.md#no-such", "../../x.md"]


def test_slugs_follow_github():
    assert slug("TEDI (Eq. 5–6) and its calibration (Eq. 7)") == "tedi-eq-56-and-its-calibration-eq-7"
    assert slug("Image forms: `paper` or `mean_log`") == "image-forms-paper-or-mean_log"


# -- the repository -----------------------------------------------------------------------------------


def test_scope_is_scanned():
    files = {f.relative_to(ROOT).as_posix() for f in scanned_files()}
    for must in ("README.md", "core/ptedi.py", "drivers/davis/protocol.py", "docs/method.md"):
        assert must in files


@pytest.mark.parametrize("path", scanned_files(), ids=lambda p: p.relative_to(ROOT).as_posix())
def test_no_citation_of_the_private_reference_notes(path):
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:  # an image: no path to the notes in its bytes (metadata) either
        text = path.read_bytes().decode("latin-1")
    hits = private_citations(text, path)
    assert not hits, f"{path.relative_to(ROOT)} cites the private reference notes:\n" + "\n".join(hits)


def test_docs_pages_exist_and_the_index_links_every_page():
    pages = {p.name for p in DOCS.glob("*.md")}
    assert {"README.md", "method.md", "baselines.md", "davis-protocol.md", "file-formats.md", "simulator.md"} <= pages
    linked = {t.partition("#")[0] for t in relative_links(DOCS / "README.md")}
    assert pages - {"README.md"} <= linked
    assert any(t.startswith("docs/") for t in relative_links(ROOT / "README.md"))


@pytest.mark.parametrize("md", link_sources(), ids=lambda p: p.relative_to(ROOT).as_posix())
def test_relative_links_resolve(md):
    assert not broken_links(md), f"{md.relative_to(ROOT)}: " + "; ".join(broken_links(md))


def test_every_command_line_flag_is_documented():
    """Every flag a user can see in ``--help`` is described somewhere in docs/ (the option lists of
    commands.md and the pages it links), so the docs cannot fall behind the parser."""
    import argparse

    from necviz.commands.cli import build_parser

    doc = "\n".join(f.read_text(encoding="utf-8") for f in DOCS.glob("*.md"))
    missing = set()

    def walk(parser):
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for sub in action.choices.values():
                    walk(sub)
            elif action.help != argparse.SUPPRESS:
                missing.update(
                    o
                    for o in action.option_strings
                    if o.startswith("--")
                    and o != "--help"
                    and not re.search(rf"(?<![\w-]){re.escape(o)}(?![\w-])", doc)
                )

    walk(build_parser())
    assert sorted(missing) == []


def test_the_public_api_has_numpydoc_sections():
    """What a user calls first says what it takes, what it gives and what it refuses (numpydoc)."""
    import inspect

    import necviz
    import necviz.options as O
    from necviz.core import control
    from necviz.core.ptedi import PeripheralEstimator
    from necviz.drivers.recordings import open_recording
    from necviz.pipeline import Lane, Pipeline

    want = {
        necviz.run_demo: "PRX",
        necviz.run_replay: "PRX",
        necviz.run_live: "PRX",
        necviz.run_compare: "PRX",
        open_recording: "PRX",
        Pipeline: "P",
        Lane: "P",
        PeripheralEstimator: "P",
        control.make_controller: "PRX",
        control.register_controller: "PX",
    }
    for name in (
        "SceneOptions",
        "ViewerOptions",
        "ShowOptions",
        "TuneOptions",
        "ClipOptions",
        "VideoOptions",
        "DemoOptions",
        "ReplayOptions",
        "ExportOptions",
        "LiveOptions",
        "CompareOptions",
    ):
        want[getattr(O, name)] = "P"
    for name in (
        "NECController",
        "NavidController",
        "ShimController",
        "BeginController",
        "NECOptions",
        "NavidOptions",
        "ShimOptions",
        "BeginOptions",
    ):
        want[getattr(control, name)] = "P"
    sections = {"P": "Parameters\n----------", "R": "Returns\n-------", "X": "Raises\n------"}
    missing = []
    for obj, need in want.items():
        doc = inspect.getdoc(obj) or ""
        missing += [f"{obj.__qualname__}: {sections[k].splitlines()[0]}" for k in need if sections[k] not in doc]
    assert missing == []


def test_a_results_file_records_the_command_that_reproduces_it():
    """``necviz.bench.timing.command_line``: the options set away from their defaults, in the parser's
    order, so the results page shows a command that makes the same file (floats as %g)."""
    import argparse

    from necviz.bench.timing import command_line

    ap = argparse.ArgumentParser()
    ap.add_argument("--rounds", type=int, default=9)
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--json")
    assert command_line("benchmarks/x.py", ap, ap.parse_args([])) == "python benchmarks/x.py"
    args = ap.parse_args(["--json", "out.json", "--duration", "2.50", "--rounds", "9"])
    assert command_line("benchmarks/x.py", ap, args) == "python benchmarks/x.py --duration 2.5 --json out.json"


def test_an_alternated_benchmark_prints_each_condition_s_median_against_the_base():
    """``necviz.bench.timing.median_table``: the median run of each condition, its real-time factor and the
    last column against the base condition's median."""
    import io

    from necviz.bench.timing import median_table

    out = io.StringIO()
    walls = {"idle": [0.5, 0.4, 0.6], "busy": [1.0, 0.8, 2.0]}
    med = median_table(walls, 10.0, "other CPU", "idle", ("x idle", lambda w, base: w / base), out=out)
    assert med == {"idle": 0.5, "busy": 1.0}
    rows = [line.split() for line in out.getvalue().splitlines()[2:]]
    assert rows == [["idle", "20.0", "0.500", "1.000"], ["busy", "10.0", "1.000", "2.000"]]
