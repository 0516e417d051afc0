"""``necviz sweep report``: per-cell means with 95 % confidence intervals, as Markdown, CSV and plots.

A *cell* is every run of the grid that differs only in its seed (same scenario, parameters,
simulator overrides, profile, controller and controller parameters). For each chosen metric the
cell's value is the mean over its seeds with the half-width of the 95 % confidence interval,
Student's t on the per-seed values (:func:`necviz.core.metrics.confidence_interval`, the same figures
``necviz compare --seeds N`` prints). A metric some seed has no value for (``recovery_ms`` when a
controller never recovered) has no mean; the table says how many seeds lack it.

Metrics are whatever numeric columns the runs wrote (listed in each row's metadata): the sweep
file's ``metrics = [...]`` or ``--metrics`` choose among them, the default is all of them.

Files (in ``OUT/report/`` unless ``--out``): ``report.md`` (one table per scenario: the swept
parameters, the controller, seeds, mean ± CI per metric), ``cells.csv`` (every cell: parameters,
counts, mean, CI, standard deviation, values and missing per metric), ``runs.csv`` (every row),
and PNG plots: for each scenario and each swept parameter, the plot metrics against that
parameter, one line per controller configuration with its confidence band; a scenario without
swept parameters gets a bar chart per controller with CI error bars.
"""

from __future__ import annotations

import csv
import io
import json
import math
import re
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from necviz.core.errors import ParameterError
from necviz.core.metrics import confidence_interval
from necviz.sweeps.spec import cell_key
from necviz.sweeps.store import REPORT_FILES, Store, SweepDirError

PLOT_DEFAULT = ("saturated_frames_50", "recovery_ms")
SPEC_FIXED = ("scenario", "duration_s", "profile", "sift", "markers", "controller")
SPEC_PREFIXES = ("scenario_params.", "controller_params.", "sim.")
NOT_DATA = {"traceback", "spec_json", "__metrics__"}


@dataclass
class Cell:
    """One cell: its spec columns, its rows' seeds and the per-metric statistics."""

    key: str
    columns: dict
    seeds: list = field(default_factory=list)
    failed: int = 0
    values: dict = field(default_factory=dict)  # metric -> per-seed values (None where missing)
    stats: dict = field(default_factory=dict)  # metric -> {mean, ci95, std, n, missing}

    @property
    def n(self) -> int:
        return len(self.seeds)


def is_spec_column(name: str) -> bool:
    return name in SPEC_FIXED or name.startswith(SPEC_PREFIXES)


def available_metrics(rows) -> list[str]:
    """Numeric metric columns of the ok rows, in the order they first appear (all-empty ones left out)."""
    seen: OrderedDict = OrderedDict()
    for r in rows:
        if r.get("status") != "ok":
            continue
        for m in r.get("__metrics__", []):
            if r.get(m) is not None:
                seen[m] = True
    return list(seen)


def choose_metrics(rows, wanted=None) -> list[str]:
    have = available_metrics(rows)
    if not wanted:
        return have
    bad = [m for m in wanted if m not in have]
    if bad:
        raise ParameterError(
            f"metrics: {', '.join(repr(m) for m in bad)} not among the runs' metrics "
            f"({', '.join(have) or 'none: no run finished'})"
        )
    return list(wanted)


def _num(v):
    if v is None or isinstance(v, bool):
        return None if v is None else float(v)
    v = float(v)
    return v if math.isfinite(v) else None


def build_cells(rows, metrics) -> list[Cell]:
    """Group rows by cell (the spec without its seed) and compute each metric's statistics."""
    groups: OrderedDict[str, Cell] = OrderedDict()
    for r in rows:  # in grid order: the cells come out as the sweep file lists them
        spec = json.loads(r["spec_json"])
        k = cell_key(spec)
        cell = groups.get(k)
        if cell is None:
            cell = groups[k] = Cell(k, {c: v for c, v in r.items() if is_spec_column(c)})
        if r.get("status") != "ok":
            cell.failed += 1
            continue
        cell.seeds.append(r.get("seed"))
        for m in metrics:
            cell.values.setdefault(m, []).append(_num(r.get(m)))
    for cell in groups.values():
        for c, v in list(cell.columns.items()):  # a column some rows of the cell lack
            cell.columns.setdefault(c, v)
        for m in metrics:
            vals = cell.values.get(m, [])
            got = [v for v in vals if v is not None]
            missing = len(vals) - len(got)
            if not vals or missing:
                cell.stats[m] = {"mean": None, "ci95": None, "std": None, "n": len(got), "missing": missing}
                continue
            mean, ci = confidence_interval(got)
            cell.stats[m] = {
                "mean": mean,
                "ci95": ci,
                "std": float(np.std(got, ddof=1)) if len(got) > 1 else 0.0,
                "n": len(got),
                "missing": 0,
            }
    return list(groups.values())


def _seeds_text(seeds) -> str:
    s = sorted(x for x in seeds if x is not None)
    if not s:
        return "–"
    if s == list(range(s[0], s[-1] + 1)) and len(s) > 2:
        return f"{s[0]}..{s[-1]}"
    return ",".join(str(x) for x in s)


def fmt(v, ci=None) -> str:
    if v is None:
        return "—"
    if not ci and float(v).is_integer() and abs(v) < 1e12:
        return str(int(v))
    a = abs(v)
    d = 0 if a >= 1000 else 1 if a >= 10 else 2 if a >= 1 else 3
    s = f"{v:.{d}f}"
    if ci is not None and ci > 0:
        s += f" ± {ci:.{d}f}"
    return s


def _value_text(v) -> str:
    if v is None:
        return "none"
    if isinstance(v, float) and v.is_integer() and abs(v) < 1e15:
        return str(int(v)) if abs(v) < 1e6 else f"{v:g}"
    return str(v)


def _short(col: str) -> str:
    for p in ("scenario_params.", "controller_params."):
        if col.startswith(p):
            return col[len(p) :]
    return col


def varying(cells, exclude=("scenario", "controller")) -> list[str]:
    """Spec columns whose value differs between the cells (the swept parameters), controller params last."""
    cols: OrderedDict = OrderedDict()
    for c in cells:
        for k in c.columns:
            cols[k] = True
    out = []
    for k in cols:
        if k in exclude:
            continue
        vals = {json.dumps(c.columns.get(k), sort_keys=True, default=str) for c in cells}
        if len(vals) > 1:
            out.append(k)
    return sorted(out, key=lambda k: (k.startswith("controller_params."), k))


def controller_label(columns: dict, skip: str | None = None) -> str:
    params = [
        f"{_short(k)}={_value_text(v)}"
        for k, v in sorted(columns.items())
        if k.startswith("controller_params.") and k != skip and v is not None
    ]
    return columns.get("controller", "?") + (f" ({', '.join(params)})" if params else "")


# -- the files -------------------------------------------------------------------------------------
def markdown(title: str, intro: list[str], cells, metrics) -> str:
    out = [f"# {title}", "", *intro, ""]
    by_scen: OrderedDict = OrderedDict()
    for c in cells:
        by_scen.setdefault(c.columns.get("scenario"), []).append(c)
    for scen, cs in by_scen.items():
        axes = [a for a in varying(cs) if not a.startswith("controller_params.")]
        out += [f"## {scen}", ""]
        head = [_short(a) for a in axes] + ["controller", "seeds"] + metrics
        if any(c.failed for c in cs):
            head.insert(len(axes) + 2, "failed")
        out.append("| " + " | ".join(head) + " |")
        out.append("|" + "---|" * len(head))
        for c in cs:
            row = [_value_text(c.columns.get(a)) for a in axes] + [controller_label(c.columns), str(c.n)]
            if any(x.failed for x in cs):
                row.append(str(c.failed))
            for m in metrics:
                st = c.stats.get(m) or {}
                cell = fmt(st.get("mean"), st.get("ci95"))
                if st.get("missing"):
                    cell += f" ({st['missing']}/{st['missing'] + st['n']} missing)"
                row.append(cell)
            out.append("| " + " | ".join(x.replace("|", "\\|") for x in row) + " |")
        out.append("")
    return "\n".join(out)


def cells_csv(cells, metrics) -> str:
    cols: OrderedDict = OrderedDict((k, True) for k in SPEC_FIXED)
    for c in cells:
        for k in c.columns:
            cols[k] = True
    head = list(cols) + ["seeds", "runs_ok", "runs_failed"]
    for m in metrics:
        head += [f"{m}.mean", f"{m}.ci95", f"{m}.std", f"{m}.n", f"{m}.missing"]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(head)
    for c in cells:
        row = [c.columns.get(k) for k in cols] + [_seeds_text(c.seeds), c.n, c.failed]
        for m in metrics:
            st = c.stats.get(m) or {}
            row += [st.get("mean"), st.get("ci95"), st.get("std"), st.get("n"), st.get("missing")]
        w.writerow(["" if v is None else v for v in row])
    return buf.getvalue()


def runs_csv(rows) -> str:
    cols: OrderedDict = OrderedDict()
    for r in rows:
        for k in r:
            if k not in NOT_DATA:
                cols[k] = True
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(list(cols))
    for r in rows:
        w.writerow(["" if r.get(k) is None else r.get(k) for k in cols])
    return buf.getvalue()


def _safe(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", str(text)).strip("_") or "x"


def _save(fig, path: Path) -> None:
    from necviz.outputs import atomic_write

    with atomic_write(path, "wb") as f:
        fig.savefig(f, format="png", dpi=110)


def plots(cells, metrics, folder: Path) -> list[Path]:
    """PNG plots (see the module docstring); returns the files written."""
    from matplotlib.figure import Figure

    written = []
    by_scen: OrderedDict = OrderedDict()
    for c in cells:
        by_scen.setdefault(c.columns.get("scenario"), []).append(c)
    for scen, cs in by_scen.items():
        axes = varying(cs)
        if not axes:
            fig = Figure(figsize=(4.2 * len(metrics), 3.4), layout="constrained")
            for i, m in enumerate(metrics):
                ax = fig.add_subplot(1, len(metrics), i + 1)
                labels = [controller_label(c.columns) for c in cs]
                means = [(c.stats.get(m) or {}).get("mean") for c in cs]
                cis = [(c.stats.get(m) or {}).get("ci95") or 0.0 for c in cs]
                ax.bar(
                    range(len(cs)), [np.nan if v is None else v for v in means], yerr=cis, capsize=3, color="#4c72b0"
                )
                ax.set_xticks(range(len(cs)), labels, rotation=30, ha="right", fontsize=8)
                ax.set_title(m, fontsize=9)
            fig.suptitle(f"{scen}: mean ± 95 % CI over seeds", fontsize=10)
            path = folder / f"plot-{_safe(scen)}.png"
            _save(fig, path)
            written.append(path)
            continue
        for axis in axes:
            fig = Figure(figsize=(4.6 * len(metrics), 3.6), layout="constrained")
            others = [a for a in axes if a != axis and not a.startswith("controller_params.")]
            lines: OrderedDict = OrderedDict()
            for c in cs:
                if axis not in c.columns:
                    continue
                label = controller_label(c.columns, skip=axis)
                extra = [f"{_short(a)}={_value_text(c.columns.get(a))}" for a in others]
                lines.setdefault(label + (f" [{', '.join(extra)}]" if extra else ""), []).append(c)
            xs_all = [c.columns.get(axis) for group in lines.values() for c in group]
            numeric = all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in xs_all)
            cats = sorted({_value_text(x) for x in xs_all}) if not numeric else None
            for i, m in enumerate(metrics):
                ax = fig.add_subplot(1, len(metrics), i + 1)
                for label, group in lines.items():
                    group = sorted(
                        group,
                        key=lambda c: c.columns.get(axis) if numeric else cats.index(_value_text(c.columns.get(axis))),
                    )
                    x = [
                        c.columns.get(axis) if numeric else cats.index(_value_text(c.columns.get(axis))) for c in group
                    ]
                    y = np.array(
                        [np.nan if (c.stats.get(m) or {}).get("mean") is None else c.stats[m]["mean"] for c in group]
                    )
                    e = np.array([(c.stats.get(m) or {}).get("ci95") or 0.0 for c in group])
                    (ln,) = ax.plot(x, y, marker="o", label=label)
                    ax.fill_between(x, y - e, y + e, alpha=0.2, color=ln.get_color(), linewidth=0)
                if cats is not None:
                    ax.set_xticks(range(len(cats)), cats)
                ax.set_xlabel(_short(axis))
                ax.set_title(m, fontsize=9)
                ax.grid(alpha=0.3)
            handles, labels = fig.axes[0].get_legend_handles_labels()
            if handles:
                fig.legend(handles, labels, loc="outside right upper", fontsize=7)
            fig.suptitle(f"{scen}: against {_short(axis)} (mean, 95 % CI band over seeds)", fontsize=10)
            path = folder / f"plot-{_safe(scen)}-{_safe(_short(axis))}.png"
            _save(fig, path)
            written.append(path)
    return written


def report(out, metrics=None, folder=None, force: bool = False, plot_metrics=None, stream=None) -> dict:
    """Write the report of the sweep in ``out`` (see the module docstring); returns what it wrote."""
    from necviz.outputs import atomic_write

    store = Store(out)
    m = store.manifest()
    grid = [g["hash"] for g in m.get("grid", [])]
    folder = Path(folder) if folder is not None else store.root / "report"
    if folder.exists() and not folder.is_dir():
        raise SweepDirError(f"--out: {folder} is a file, not a folder")
    if not folder.exists() and not folder.parent.is_dir():
        from necviz.outputs import make_folder

        make_folder(folder.parent, "--out")
    existing = [folder / f for f in REPORT_FILES if (folder / f).exists()]
    if existing and not force:
        raise SweepDirError(f"{existing[0]} already exists; pass --force to replace the report")
    rows = store.read_rows(grid, skip_bad=True)
    note = store.unreadable_note(m.get("sweep_file"))
    if note and stream is not None:
        print(f"warning: {note}", file=stream)
    if not rows:
        raise SweepDirError(f"{store.root} holds no finished runs yet (see `necviz sweep status {store.root}`)")
    wanted = metrics if metrics else m.get("metrics")
    chosen = choose_metrics(rows, wanted)
    cells = build_cells(rows, chosen)
    ok = sum(r.get("status") == "ok" for r in rows)
    git = m.get("git") or {}
    intro = [
        f"{len(rows)} of {len(grid)} runs ({ok} ok, {len(rows) - ok} failed) from `{m.get('sweep_file')}`; "
        f"necviz {m.get('versions', {}).get('necviz')}"
        + (f", git {git.get('revision', '')[:10]}{' (modified)' if git.get('dirty') else ''}" if git else "")
        + ".",
        "",
        "Each value is the mean over the cell's seeds ± the half-width of its 95 % confidence interval "
        "(Student's t); *seeds* is how many runs the cell has.",
    ]
    folder.mkdir(exist_ok=True)
    if force:
        for p in folder.glob("plot-*.png"):
            p.unlink()
    files = {}
    for name, text in (
        ("report.md", markdown(f"Sweep report: {m.get('name') or store.root.name}", intro, cells, chosen)),
        ("cells.csv", cells_csv(cells, chosen)),
        ("runs.csv", runs_csv(rows)),
    ):
        with atomic_write(folder / name) as f:
            f.write(text)
        files[name] = str(folder / name)
    pm = [x for x in (plot_metrics or PLOT_DEFAULT) if x in chosen] or chosen[:2]
    pngs = plots(cells, pm, folder) if pm else []
    result = {
        "folder": str(folder),
        "files": files,
        "plots": [str(p) for p in pngs],
        "metrics": chosen,
        "cells": len(cells),
        "rows": len(rows),
        "ok": ok,
        "table": [{"columns": c.columns, "seeds": c.seeds, "failed": c.failed, "stats": c.stats} for c in cells],
    }
    if stream is not None:
        print(f"report: {len(cells)} cells from {len(rows)} runs; metrics: {', '.join(chosen)}", file=stream)
        for p in [*files.values(), *result["plots"]]:
            print(f"  wrote {p}", file=stream)
    return result


__all__ = ["Cell", "available_metrics", "build_cells", "choose_metrics", "report"]
