"""The options and defaults docs/commands.md states are the parser's.

Read from the docs, compared with ``build_parser()``: every flag a command's option list names is
one of its flags; every flag of a command is named in its list, in the option groups it shares
(scene options, the dashboard commands' options, the viewer flags in docs/dashboard.md, the
benches' ``--json``/``--force``); every number given in parentheses after a flag, and every list
of default controllers, is the parser's default.
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import pytest

from necviz.commands.cli import build_parser
from necviz.names import BASELINES

DOCS = Path(__file__).resolve().parents[1] / "docs"


def _read(name: str) -> str:
    """A docs page with its lines joined into paragraphs (a phrase may wrap anywhere)."""
    return re.sub(r"(?<!\n)\n(?!\n)", " ", (DOCS / name).read_text(encoding="utf-8"))


COMMANDS = _read("commands.md")
DASHBOARD = _read("dashboard.md")
FLAG = re.compile(r"(--[a-z][a-z0-9-]*)")


def _subparsers(p: argparse.ArgumentParser, prefix: tuple = ()) -> dict[str, argparse.ArgumentParser]:
    out = {}
    for a in p._actions:
        if isinstance(a, argparse._SubParsersAction):
            for name, sp in a.choices.items():
                out[" ".join((*prefix, name))] = sp
                out.update(_subparsers(sp, (*prefix, name)))
    return out


PARSERS = _subparsers(build_parser())


def _flags(cmd: str) -> dict[str, argparse.Action]:
    """The command's long flags, but --help and those hidden from its --help (test hooks)."""
    return {
        o: a
        for a in PARSERS[cmd]._actions
        for o in a.option_strings
        if o.startswith("--") and o != "--help" and a.help != argparse.SUPPRESS
    }


def _spans() -> dict[str, str]:
    """Command -> the text of its "Options of `CMD`:" lists (a list ends at the next one, a paragraph
    break, or a sentence that starts with another command's name in backticks)."""
    names = "|".join(sorted((re.escape(c) for c in PARSERS), key=len, reverse=True))
    head = re.compile(r"Options of `([a-z ]+)`(?: and `([a-z ]+)`)?([^:]*):", re.S)
    stop = re.compile(r"Options of `|All three dashboard commands|Every bench takes|\n\n|\.\s+`(?:" + names + r")[ `]")
    spans: dict[str, str] = {}
    for m in head.finditer(COMMANDS):
        end = stop.search(COMMANDS, m.end())
        text = COMMANDS[m.end() : end.start() if end else len(COMMANDS)]
        for cmd in (c for c in m.group(1, 2) if c):
            spans[cmd] = spans.get(cmd, "") + "\n" + text
    return spans


SPANS = _spans()


def _paragraph(start: str, text: str = COMMANDS) -> str:
    i = text.index(start)
    j = text.find("\n\n", i)
    return text[i : j if j >= 0 else len(text)]


SCENE = _paragraph("Scene options (")
DASH = COMMANDS[COMMANDS.index("All three dashboard commands") : COMMANDS.index("Options of `compare`")]
VIEWER = DASHBOARD[DASHBOARD.index("**Viewer flags**") : DASHBOARD.index("**Entity schema**")]
BENCH = "`--json FILE` and `--force`" if "Every bench takes `--json FILE` and `--force`" in COMMANDS else ""
SHARED = {
    "demo": SCENE + DASH + VIEWER,
    "live": SCENE + DASH + VIEWER,
    "replay": DASH + VIEWER,
    "compare": SCENE,
    "bench sim": SCENE + BENCH,
    "bench estimators": BENCH,
    "bench decode": BENCH,
    "bench pipeline": BENCH,
}
LISTED = sorted(SPANS)


def test_the_docs_list_options_for_the_main_commands():
    for cmd in ("demo", "replay", "live", "compare", "export", "calibrate", "bench sim", "bench pipeline"):
        assert cmd in SPANS, f"docs/commands.md has no 'Options of `{cmd}`' list"


@pytest.mark.parametrize("cmd", LISTED)
def test_every_flag_the_docs_name_is_the_commands(cmd):
    unknown = sorted(set(FLAG.findall(SPANS[cmd])) - set(_flags(cmd)))
    assert not unknown, f"docs/commands.md lists {', '.join(unknown)} under `{cmd}`, which it does not take"


@pytest.mark.parametrize("cmd", LISTED)
def test_every_flag_of_the_command_is_in_the_docs(cmd):
    documented = set(FLAG.findall(SPANS[cmd] + SHARED.get(cmd, "")))
    missing = sorted(set(_flags(cmd)) - documented)
    assert not missing, f"`necviz {cmd}` takes {', '.join(missing)}, which docs/commands.md does not list for it"


def _number(text: str) -> float:
    return float(text.replace(",", ""))


@pytest.mark.parametrize("cmd", LISTED)
def test_numbers_in_parentheses_are_the_parsers_defaults(cmd):
    """`--flag` (N), `--flag X` (N ...) or `--flag` (default N): N is the parser's default."""
    flags = _flags(cmd)
    pattern = re.compile(r"`(--[a-z][a-z0-9-]*)[^`]*`\s*\((?:default\s+)?`?(\d[\d,]*(?:\.\d+)?)")
    stated = [(f, n) for f, n in pattern.findall(SPANS[cmd] + SHARED.get(cmd, "")) if f in flags]
    for flag, n in stated:
        default = flags[flag].default
        if cmd in ("demo", "live") and flag == "--duration":  # the scene options' "(default: the scenario's)"
            continue
        assert isinstance(default, (int, float)) and not isinstance(default, bool), (cmd, flag, default)
        assert _number(n) == pytest.approx(float(default)), f"docs: `{cmd} {flag}` ({n}); parser: {default}"


def _controllers_in(text: str) -> list[str]:
    """Controller names a default is stated with: backticked names, "the five baselines" as BASELINES."""
    names = re.findall(r"`([a-z][a-z-]*)`", text)
    if "the five baselines" in text:
        names += list(BASELINES)
    return names


@pytest.mark.parametrize("cmd", ["demo", "compare"])
def test_the_default_controllers_are_the_parsers(cmd):
    m = re.search(r"`--controllers`\s*\(([^)]*)\)", SPANS[cmd])
    assert m and "default" in m.group(1), f"docs/commands.md states no default for `{cmd} --controllers`"
    stated = m.group(1).split("default", 1)[1].split(";")[0]
    parser = PARSERS[cmd].get_default("controllers").split(",")
    assert sorted(_controllers_in(stated)) == sorted(parser), (stated, parser)
    assert "all six" not in m.group(1)


def test_the_sweep_file_in_the_docs_is_the_shipped_example():
    """docs/sweeps.md shows benchmarks/sweeps/example.toml as it is (a copy must not, e.g., run the slow SIFT metric)."""
    import tomllib

    text = (DOCS / "sweeps.md").read_text(encoding="utf-8")
    block = re.search(r"```toml\n(.*?)```", text, re.S)
    assert block, "docs/sweeps.md shows no sweep file"
    shipped = tomllib.loads((DOCS.parent / "benchmarks" / "sweeps" / "example.toml").read_text(encoding="utf-8"))
    assert tomllib.loads(block.group(1)) == shipped
    assert shipped.get("sift") is False


def test_the_docs_index_lists_each_page_once_and_examples_use_no_private_paths():
    index = (DOCS / "README.md").read_text(encoding="utf-8")
    pages = re.findall(r"^\| \[([\w.-]+\.md)\]", index, re.M)
    assert pages and len(pages) == len(set(pages)), sorted(p for p in pages if pages.count(p) > 1)
    examples = DOCS.parent / "examples"
    for f in [examples / "README.md", *examples.glob("*.py")]:
        assert "/work/" not in f.read_text(encoding="utf-8"), f"{f.name} names a path users do not have"


def test_the_web_viewer_docs_name_its_url_and_forward_both_ports():
    from necviz.names import DEFAULT_GRPC_PORT, DEFAULT_WEB_PORT

    text = (DOCS / "dashboard.md").read_text(encoding="utf-8")
    data = f"rerun+http://127.0.0.1:{DEFAULT_GRPC_PORT}/proxy"
    url = f"http://127.0.0.1:{DEFAULT_WEB_PORT}/?url={data.replace('+', '%2B')}"  # as viewer.start_web_server builds it
    assert f"web viewer: {url}" in text
    assert (
        f"-L {DEFAULT_WEB_PORT}:127.0.0.1:{DEFAULT_WEB_PORT} -L {DEFAULT_GRPC_PORT}:127.0.0.1:{DEFAULT_GRPC_PORT}"
        in text
    )


def test_info_lists_every_controller_the_commands_accept_tuned_ones_included():
    """docs/commands.md: "every registered name, tuned baselines included, is listed by `necviz info`"
    (a fresh process: in this one another test may have registered the tuned controllers already)."""
    import subprocess
    import sys

    from necviz.names import CONTROLLER_NAMES

    assert "tuned baselines included, is listed by `necviz info`" in COMMANDS
    out = subprocess.run([sys.executable, "-m", "necviz", "info"], capture_output=True, text=True, timeout=120)
    line = next(ln for ln in out.stdout.splitlines() if ln.startswith("controllers:"))
    assert sorted(n.strip() for n in line.split(":", 1)[1].split(",")) == sorted(CONTROLLER_NAMES), line
