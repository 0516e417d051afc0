#!/usr/bin/env python
"""The "What events add" tables from committed sweep outputs: paired differences with 95 % CIs over seeds.

Reads one or more sweep folders (``necviz sweep run FILE --out DIR``; the evaluation's five are
``benchmarks/sweeps/{heldout,ladder,ceiling,latency,transition}.toml``) and writes Markdown tables:

1. **NEC − nec-frames** (what the events add: the same controller with and without its events), per
   held-out scene and per scene family (the preset it was drawn from), under the simulator's defaults;
2. the same difference **over the event bus ceiling** (6, 12, 20 Mev/s, none), the **command latency**
   (0.2, 1, 5 ms) and the **transition time** of the held-out tunnel exits;
3. the **ladder** from the paper's controller (``nec-paper``) to NEC's default, one necviz addition at
   a time: each rung's mean and its difference from the rung before;
4. every **baseline, published and tuned** (``NAME`` against ``NAME-tuned``).

Pairing (docs/evaluation.md): two lanes are compared on the same scene, seed and simulator settings —
the same lighting, the same events; the difference is taken per seed. Within one scene the interval is
Student's t over its seeds (95 %). Over several scenes (a family, every scene) the seeds of one scene are
not independent of each other — the scene decides most of the difference — so the interval is
**clustered by scene**: Student's t over the scenes' mean differences (``n`` counts scenes), and for
every scene the headline also gives a percentile bootstrap over scenes (:func:`scene_bootstrap`) and
in how many scenes the effect lives (a scene's mean difference non-zero; :func:`scene_counts`).
``nec-frames`` never receives an event, so its runs do not depend on the ceiling: NEC at every ceiling
is paired with ``nec-frames`` at the same scene, seed, latency and transition. A negative difference
in saturated frames means the first lane saturated fewer frames.

Inputs are sweep folders or a rows file this script wrote (``--rows FILE.csv``: one line per run with
the pairing keys and the metrics, a few hundred kB where the folders' per-frame Parquet files take
tens of MB); the evaluation's rows are committed as ``benchmarks/results/events_rows.csv``, so the
tables regenerate without re-running the sweeps.

usage: python benchmarks/events_table.py DIR|ROWS.csv [...] [--metric saturated_frames_50] [--out FILE.md]
       [--json FILE] [--rows FILE.csv]
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

#: the simulator's defaults, for rows that do not set them
DEFAULT_CEILING = 12e6
DEFAULT_LATENCY_US = 1000.0
#: the ladder's rungs in order (sweeps/ladder.toml; its ends run in sweeps/heldout.toml)
LADDER = ("nec-paper", "nec@bound", "nec@median", "nec@goal", "nec@escape", "nec")
#: what every rung keeps of necviz's where the paper is silent (nec-paper included; docs/method.md)
LADDER_KEPT = (
    "f_w's smoothstep and dead band, min_command_change, the stale-command re-send, the 50 % valid-pixel "
    "skip threshold, the first anchor on any frame"
)
LADDER_STEP = {
    "nec@bound": "+ saturation bound",
    "nec@median": "+ median metering",
    "nec@goal": "+ measured goal (100 DN)",
    "nec@escape": "+ escape rule",
    "nec": "+ lagging events absorbed at a bound, + the flicker rule (the default)",
}
BASELINES = ("navid", "shim", "begin")


def t_ci(values) -> tuple[float, float, int]:
    """``(mean, 95 % half-width, n)`` of the finite values (Student's t; half-width 0 for one value)."""
    v = np.asarray([x for x in values if x is not None and math.isfinite(x)], dtype=np.float64)
    if v.size == 0:
        return math.nan, math.nan, 0
    if v.size < 2:
        return float(v.mean()), 0.0, 1
    from scipy.stats import t

    return float(v.mean()), float(t.ppf(0.975, v.size - 1) * v.std(ddof=1) / math.sqrt(v.size)), int(v.size)


def clustered(by_scene) -> tuple[float, float, int]:
    """``(mean, 95 % half-width, scenes)``: Student's t over the scenes' mean paired differences.

    ``by_scene``: ``{scene: [(seed, diff, a, b), ...]}`` (:func:`paired`). With the same seeds in every
    scene the mean equals the mean over pairs; the interval treats a scene, not a pair, as the replicate.
    """
    means = [float(np.mean([x[1] for x in items])) for items in by_scene.values() if items]
    return t_ci(means)


def scene_bootstrap(by_scene, resamples: int = 10_000, seed: int = 0) -> tuple[float, float]:
    """95 % percentile bootstrap interval of the mean paired difference, resampling whole scenes (with
    their seeds) with replacement; a fixed generator seed, so the interval is reproducible."""
    groups = [np.asarray([x[1] for x in items], np.float64) for items in by_scene.values() if items]
    if not groups:
        return math.nan, math.nan
    sums = np.array([g.sum() for g in groups])
    counts = np.array([g.size for g in groups], np.float64)
    rng = np.random.default_rng(seed)
    pick = rng.integers(0, len(groups), size=(resamples, len(groups)))
    boot = sums[pick].sum(axis=1) / counts[pick].sum(axis=1)
    lo, hi = np.percentile(boot, [2.5, 97.5])
    return float(lo), float(hi)


def scene_counts(by_scene) -> dict:
    """In how many scenes the effect lives: scenes whose mean difference is below / above / at zero, those
    whose interval over seeds excludes zero, and the pairs that are exactly zero."""
    out = {"scenes": 0, "negative": 0, "positive": 0, "zero": 0, "significant": 0, "pairs": 0, "zero_pairs": 0}
    for items in by_scene.values():
        d = [x[1] for x in items]
        if not d:
            continue
        m, ci, _ = t_ci(d)
        out["scenes"] += 1
        out["negative" if m < 0 else "positive" if m > 0 else "zero"] += 1
        out["significant"] += bool(m != 0 and math.isfinite(ci) and abs(m) > ci)
        out["pairs"] += len(d)
        out["zero_pairs"] += sum(1 for x in d if x == 0)
    return out


def scene_name(label: str) -> str:
    """``../heldout/tunnel_exit_1003.toml`` -> ``tunnel_exit_1003``; a preset stays as it is."""
    return Path(str(label)).stem if str(label).endswith(".toml") else str(label)


def family(scene: str) -> str:
    """The preset a held-out scene was drawn from (``tunnel_exit_1003`` -> ``tunnel_exit``)."""
    return re.sub(r"_\d+$", "", scene)


def _num(v, default):
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return default
    return float(v)


#: the columns of a rows file before the metrics
ROW_KEYS = ("scene", "family", "seed", "controller", "ceiling", "latency_us", "transition_ms")


def write_rows_csv(path, rows: list[dict], metrics: list[str]) -> None:
    """The reduced rows (pairing keys, then ``metrics``), one line per run, sorted for a stable diff."""
    import csv

    def text(v) -> str:
        return (
            "" if v is None or (isinstance(v, float) and math.isnan(v)) else repr(v) if isinstance(v, float) else str(v)
        )

    keyed = sorted(rows, key=lambda r: tuple(str(r[k]) for k in ROW_KEYS))
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow([*ROW_KEYS, *metrics])
        for r in keyed:
            w.writerow([text(r.get(k)) for k in (*ROW_KEYS, *metrics)])


def read_rows_csv(path, metrics) -> list[dict]:
    """Rows written by :func:`write_rows_csv`, with their types back; a metric it lacks is an error."""
    import csv

    from necviz.core.errors import NecvizError

    with open(path, newline="", encoding="utf-8") as f:
        reader = csv.DictReader(f)
        missing = [m for m in (*ROW_KEYS, *metrics) if m not in (reader.fieldnames or ())]
        if missing:
            raise NecvizError(f"{path}: not a rows file of this script, or without {', '.join(missing)}")
        out = []
        for line, r in enumerate(reader, start=2):
            try:
                out.append(_row_from_csv(r, metrics))
            except (TypeError, ValueError) as e:
                raise NecvizError(f"{path}, line {line}: not a row of this script ({e})") from None
    return out


def _row_from_csv(r: dict, metrics) -> dict:
    """One line of a rows file with its types back (a short line reads as ``None``: a TypeError)."""
    row = {
        "scene": r["scene"],
        "family": r["family"],
        "seed": int(r["seed"]),
        "controller": r["controller"],
        "ceiling": "none" if r["ceiling"] == "none" else float(r["ceiling"]),
        "latency_us": float(r["latency_us"]),
        "transition_ms": None if r["transition_ms"] == "" else _parse(r["transition_ms"]),
    }
    row.update({m: None if r[m] == "" else float(r[m]) for m in metrics})
    return row


def _parse(v: str):
    f = float(v)
    return int(f) if f.is_integer() and "." not in v else f


def load_rows(dirs, metrics) -> list[dict]:
    """The ok rows of every sweep folder (or rows file), reduced to what pairing needs."""
    from necviz.sweeps.store import Store

    out = []
    for d in dirs:
        if str(d).endswith(".csv"):
            out += read_rows_csv(d, metrics)
            continue
        store = Store(d)
        store.manifest()  # a one-line error when DIR is not a sweep folder
        for r in store.read_rows():
            if r.get("status") != "ok":
                continue
            scene = scene_name(r["scenario"])
            ceiling = r.get("sim.dvs.max_event_rate", DEFAULT_CEILING)
            out.append(
                {
                    "scene": scene,
                    "family": family(scene),
                    "seed": int(r["seed"]),
                    "controller": r["controller"],
                    "ceiling": "none"
                    if "sim.dvs.max_event_rate" in r and ceiling is None
                    else _num(ceiling, DEFAULT_CEILING),
                    "latency_us": _num(r.get("sim.aps.latency_us"), DEFAULT_LATENCY_US),
                    "transition_ms": r.get("scenario_params.transition_ms"),
                    **{m: r.get(m) for m in metrics},
                }
            )
    return out


def index(rows) -> dict:
    """``(controller, scene, ceiling, latency, transition, seed) -> row`` (the first of duplicates)."""
    idx = {}
    for r in rows:
        key = (r["controller"], r["scene"], r["ceiling"], r["latency_us"], r["transition_ms"], r["seed"])
        idx.setdefault(key, r)
    return idx


def paired(idx, a: str, b: str, metric: str, where, b_any_ceiling: bool = False) -> dict:
    """Per-seed differences ``a - b`` over the rows of ``a`` that ``where(row)`` keeps, grouped by scene.

    Returns ``{scene: [(seed, diff, a, b), ...]}``; ``b_any_ceiling``: ``b``'s row may have any ceiling
    (``nec-frames``: identical at every ceiling), preferring the same one.
    """
    by_scene = defaultdict(list)
    others = defaultdict(list)
    if b_any_ceiling:
        for (c, s, _ceil, lat, tr, seed), r in idx.items():
            if c == b:
                others[(s, lat, tr, seed)].append(r)
    for (c, s, ceil, lat, tr, seed), ra in idx.items():
        if c != a or not where(ra):
            continue
        rb = idx.get((b, s, ceil, lat, tr, seed))
        if rb is None and b_any_ceiling and others.get((s, lat, tr, seed)):
            rb = others[(s, lat, tr, seed)][0]
        if rb is None:
            continue
        va, vb = ra.get(metric), rb.get(metric)
        if va is None or vb is None:
            continue
        by_scene[s].append((seed, float(va) - float(vb), float(va), float(vb)))
    return by_scene


def fmt(mean, ci, n=None, digits=1, what: str = "") -> str:
    """``+1.2 ± 0.4 (n=5)``; ``what`` names what ``n`` counts (``scenes``: a clustered interval)."""
    if not math.isfinite(mean):
        return "—"
    s = f"{mean:+.{digits}f}" if n is not None else f"{mean:.{digits}f}"
    if ci and ci > 0:
        s += f" ± {ci:.{digits}f}"
    if n is None:
        return s
    if what and n == 1:
        what = what.removesuffix("s")
    return s + (f" ({n} {what})" if what else f" (n={n})")


def diff_cells(by_scene) -> tuple[dict, dict]:
    """Per scene ``(mean a, mean b, mean diff, ci over seeds, seeds)`` and per family ``(mean a, mean b,
    mean diff, ci clustered by scene, scenes)`` (:func:`clustered`)."""
    scenes, fams = {}, defaultdict(list)
    for s, items in sorted(by_scene.items()):
        d = [x[1] for x in items]
        m, ci, n = t_ci(d)
        scenes[s] = (float(np.mean([x[2] for x in items])), float(np.mean([x[3] for x in items])), m, ci, n)
        fams[family(s)].extend(items)
    fam = {}
    for f, items in sorted(fams.items()):
        m, ci, n = clustered({s: v for s, v in by_scene.items() if family(s) == f})
        fam[f] = (float(np.mean([x[2] for x in items])), float(np.mean([x[3] for x in items])), m, ci, n)
    return scenes, fam


def default_condition(r) -> bool:
    return r["ceiling"] == DEFAULT_CEILING and r["latency_us"] == DEFAULT_LATENCY_US and r["transition_ms"] is None


def section_events(idx, metric, out: list, data: dict) -> None:
    by_scene = paired(idx, "nec", "nec-frames", metric, default_condition, b_any_ceiling=True)
    if not by_scene:
        return
    scenes, fams = diff_cells(by_scene)
    allpairs = [x for items in by_scene.values() for x in items]
    m, ci, n = clustered(by_scene)
    overall = (float(np.mean([x[2] for x in allpairs])), float(np.mean([x[3] for x in allpairs])), m, ci, n)
    counts = scene_counts(by_scene)
    boot = scene_bootstrap(by_scene)
    data["events"] = {
        "scenes": scenes,
        "families": fams,
        "all": overall,
        "all_bootstrap": list(boot),
        "scene_counts": counts,
    }
    out.append(f"### What events add: `nec` − `nec-frames`, {metric} (simulator defaults: 12 Mev/s, 1 ms)\n")
    out.append(
        "Per scene: paired by seed, 95 % CI over its seeds. Every scene and each family: clustered by scene "
        "(Student's t over the scenes' mean differences; n counts scenes)."
    )
    out.append(
        f"The effect lives in {counts['negative'] + counts['positive']} of {counts['scenes']} scenes "
        f"({counts['negative']} lower, {counts['positive']} higher; {counts['significant']} with an interval over "
        f"seeds that excludes 0); {counts['zero_pairs']} of {counts['pairs']} scene-seed pairs differ by exactly 0. "
        f"Bootstrap over scenes (10,000 resamples): [{boot[0]:+.2f}, {boot[1]:+.2f}].\n"
    )
    out.append("| scene | nec | nec-frames | nec − nec-frames (95 % CI) |")
    out.append("|---|---|---|---|")
    a, b, m, ci, n = overall
    out.append(f"| **every scene** | {a:.2f} | {b:.2f} | **{fmt(m, ci, n, 2, 'scenes')}** |")
    for f, (a, b, m, ci, n) in fams.items():
        out.append(f"| **{f}** (all its scenes) | {a:.2f} | {b:.2f} | **{fmt(m, ci, n, 2, 'scenes')}** |")
        for s, (a, b, m, ci, n) in scenes.items():
            if family(s) == f:
                out.append(f"| {s} | {a:.2f} | {b:.2f} | {fmt(m, ci, n, 2, 'seeds')} |")
    out.append("")


def section_sweep(idx, metric, out: list, data: dict, key: str, values, label, where_extra) -> None:
    """NEC − nec-frames per family for each value of one swept condition."""
    rows, cols = {}, []
    for v in values:
        by_scene = paired(
            idx, "nec", "nec-frames", metric, lambda r, v=v: where_extra(r, v), b_any_ceiling=(key == "ceiling")
        )
        if not by_scene:
            continue
        cols.append(v)
        _, fams = diff_cells(by_scene)
        allpairs = [x for items in by_scene.values() for x in items]
        m, ci, n = clustered(by_scene)
        fams["all"] = (float(np.mean([x[2] for x in allpairs])), float(np.mean([x[3] for x in allpairs])), m, ci, n)
        for f, cell in fams.items():
            rows.setdefault(f, {})[v] = cell
    if len(cols) < 2:
        return
    data[key] = {f: {str(v): c for v, c in cells.items()} for f, cells in rows.items()}
    out.append(f"### `nec` − `nec-frames` over the {label}, {metric}\n")
    out.append(
        "Each cell: mean of nec / nec-frames, then their paired difference ± 95 % CI clustered by scene "
        "(t over the scenes' mean differences; n scenes).\n"
    )
    out.append("| family | " + " | ".join(str(_label(key, v)) for v in cols) + " |")
    out.append("|---|" + "---|" * len(cols))
    for f in sorted(rows, key=lambda x: (x == "all", x)):
        cells = []
        for v in cols:
            c = rows[f].get(v)
            cells.append("—" if c is None else f"{c[0]:.2f} / {c[1]:.2f}: {fmt(c[2], c[3], c[4], 2, 'scenes')}")
        out.append(f"| {'**all**' if f == 'all' else f} | " + " | ".join(cells) + " |")
    out.append("")


def _label(key, v):
    if key == "ceiling":
        return "no ceiling" if v == "none" else f"{v / 1e6:g} Mev/s"
    if key == "latency_us":
        return f"{v / 1e3:g} ms"
    return f"{v:g} ms" if v is not None else "scene's own"


def section_ladder(idx, metric, out: list, data: dict) -> None:
    present = [c for c in LADDER if any(k[0] == c for k in idx)]
    if len(present) < 2:
        return
    out.append(f"### The ladder from `nec-paper` to `nec`, {metric} (simulator defaults)\n")
    out.append("Each rung adds one necviz addition to the one above it. Mean per family, then the rung's paired")
    out.append(
        "difference from the rung above ± 95 % CI clustered by scene (t over the scenes' means; n scenes). `nec-paper` is the paper where"
    )
    out.append("the paper is specific (its TEDI compensation included); every rung keeps necviz's choices where it is")
    out.append(f"silent: {LADDER_KEPT}.\n")
    fams = sorted({k[1] for k in idx if k[0] in present})
    fams = sorted({family(s) for s in fams})
    header = "| rung | " + " | ".join(fams) + " |"
    out.append(header)
    out.append("|---|" + "---|" * len(fams))
    data["ladder"] = {}
    prev = None
    for rung in present:
        cells = []
        for f in fams:
            vals = [
                r[metric]
                for k, r in idx.items()
                if k[0] == rung and family(k[1]) == f and default_condition(r) and r.get(metric) is not None
            ]
            mean = float(np.mean(vals)) if vals else math.nan
            cell = f"{mean:.2f}" if vals else "—"
            if prev is not None:
                by_scene = paired(idx, rung, prev, metric, lambda r, f=f: default_condition(r) and r["family"] == f)
                m, ci, n = clustered(by_scene)
                if n:
                    cell += f" ({fmt(m, ci, n, 2, 'scenes')})"
                data["ladder"].setdefault(rung, {})[f] = {"mean": mean, "step": [m, ci, n]}
            else:
                data["ladder"].setdefault(rung, {})[f] = {"mean": mean}
            cells.append(cell)
        if rung not in LADDER_STEP:
            name = f"`{rung}` (the paper)"
        elif prev is not None and LADDER.index(prev) == LADDER.index(rung) - 1:
            name = f"`{rung}` {LADDER_STEP[rung]}"
        else:  # rungs between did not run: the step is every addition from the rung shown above
            name = f"`{rung}` (every addition from `{prev}` on)"
        out.append(f"| {name} | " + " | ".join(cells) + " |")
        prev = rung
    out.append("")


def section_baselines(idx, metric, out: list, data: dict) -> None:
    present = [b for b in BASELINES if any(k[0] == f"{b}-tuned" for k in idx)]
    if not present:
        return
    fams = sorted({family(k[1]) for k in idx if k[0] in present})
    out.append(f"### Baselines, published and tuned, {metric} (simulator defaults)\n")
    out.append(
        "Mean per family ± 95 % CI clustered by scene (t over the scenes' means); in brackets the tuned − published "
        "paired difference, clustered the same way. `nec` for reference.\n"
    )
    out.append("| controller | " + " | ".join(fams) + " | every scene |")
    out.append("|---|" + "---|" * (len(fams) + 1))
    data["baselines"] = {}
    for name in ("nec", "nec-frames", "nec-paper", *[x for b in present for x in (b, f"{b}-tuned")]):
        if not any(k[0] == name for k in idx):
            continue
        cells = []
        for f in [*fams, "all"]:
            vals = [
                r[metric]
                for k, r in idx.items()
                if k[0] == name and (f == "all" or family(k[1]) == f) and default_condition(r)
            ]
            per_scene = defaultdict(list)
            for k, r in idx.items():
                if (
                    k[0] == name
                    and (f == "all" or family(k[1]) == f)
                    and default_condition(r)
                    and r[metric] is not None
                ):
                    per_scene[k[1]].append(float(r[metric]))
            m, ci, n = t_ci([float(np.mean(v)) for v in per_scene.values()])
            if n:
                m = float(np.mean([v for v in vals if v is not None]))  # the mean over runs; the interval over scenes
            cell = fmt(m, ci, None, 2) if n else "—"
            if name.endswith("-tuned"):
                base = name[: -len("-tuned")]
                by = paired(
                    idx, name, base, metric, lambda r, f=f: default_condition(r) and (f == "all" or r["family"] == f)
                )
                dm, dci, dn = clustered(by)
                if dn:
                    cell += f" ({fmt(dm, dci, dn, 2, 'scenes')})"
            data["baselines"].setdefault(name, {})[f] = [m, ci, n]
            cells.append(cell)
        out.append(f"| `{name}` | " + " | ".join(cells) + " |")
    out.append("")


def section_versus(idx, metric, out: list, data: dict) -> None:
    """NEC against each tuned baseline: the paired difference ``nec - NAME-tuned`` per family and over
    every scene, clustered by scene, with in how many scenes it lives (the sealed criteria's last one)."""
    present = [f"{b}-tuned" for b in BASELINES if any(k[0] == f"{b}-tuned" for k in idx)]
    if not present or not any(k[0] == "nec" for k in idx):
        return
    data["versus"] = {}
    fams = sorted({family(k[1]) for k in idx if k[0] == "nec"})
    out.append(f"### `nec` against each tuned baseline, {metric} (simulator defaults)\n")
    out.append(
        "The paired difference `nec` − baseline per family and over every scene, ± 95 % CI clustered by scene (t over "
        "the scenes' mean differences); negative: NEC has less of the metric.\n"
    )
    out.append("| baseline | " + " | ".join(fams) + " | every scene | scenes lower / higher |")
    out.append("|---|" + "---|" * (len(fams) + 2))
    for name in present:
        cells, rec = [], {}
        for f in [*fams, "all"]:
            by = paired(
                idx, "nec", name, metric, lambda r, f=f: default_condition(r) and (f == "all" or r["family"] == f)
            )
            m, ci, n = clustered(by)
            pairs = [x for items in by.values() for x in items]
            mean_pairs = float(np.mean([x[1] for x in pairs])) if pairs else math.nan
            rec[f] = [mean_pairs, ci, n]
            if f == "all":
                rec["all_bootstrap"] = list(scene_bootstrap(by))
                rec["scene_counts"] = scene_counts(by)
            cells.append(fmt(mean_pairs, ci, n, 2, "scenes") if n else "—")
        c = rec["scene_counts"]
        data["versus"][name] = rec
        out.append(f"| `{name}` | " + " | ".join(cells) + f" | {c['negative']} / {c['positive']} |")
    out.append("")


def build(dirs, metric: str = "saturated_frames_50") -> tuple[str, dict]:
    """The Markdown tables and their numbers for the sweep folders ``dirs``."""
    rows = load_rows(dirs, [metric])
    idx = index(rows)
    out, data = [], {"metric": metric, "sweeps": [str(d) for d in dirs]}
    section_events(idx, metric, out, data)
    section_sweep(
        idx,
        metric,
        out,
        data,
        "ceiling",
        [6e6, 12e6, 20e6, "none"],
        "event bus ceiling",
        lambda r, v: r["ceiling"] == v and r["latency_us"] == DEFAULT_LATENCY_US and r["transition_ms"] is None,
    )
    section_sweep(
        idx,
        metric,
        out,
        data,
        "latency_us",
        [200.0, 1000.0, 5000.0],
        "command latency",
        lambda r, v: r["latency_us"] == v and r["ceiling"] == DEFAULT_CEILING and r["transition_ms"] is None,
    )
    trans = sorted({r["transition_ms"] for r in rows if r["transition_ms"] is not None})
    section_sweep(
        idx,
        metric,
        out,
        data,
        "transition_ms",
        trans,
        "transition time (tunnel exits)",
        lambda r, v: (
            r["transition_ms"] == v and r["ceiling"] == DEFAULT_CEILING and r["latency_us"] == DEFAULT_LATENCY_US
        ),
    )
    section_ladder(idx, metric, out, data)
    section_baselines(idx, metric, out, data)
    section_versus(idx, metric, out, data)
    if not out:
        out.append("(no pairs: the folders hold no nec / nec-frames, ladder or tuned-baseline runs)\n")
    return "\n".join(out), data


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dirs", nargs="+", help="sweep folders (necviz sweep run ... --out DIR) or rows files (--rows)")
    ap.add_argument("--metric", action="append", help="metric(s) (default: saturated_frames_50 and _10)")
    ap.add_argument("--out", help="also write the Markdown here")
    ap.add_argument("--json", help="also write the numbers here")
    ap.add_argument("--rows", help="also write the runs' rows (pairing keys and the metrics) to this CSV")
    ap.add_argument("--force", action="store_true", help="replace existing --out / --json / --rows files")
    args = ap.parse_args(argv)
    from necviz.core.errors import NecvizError

    for p in (args.out, args.json, args.rows):
        if p and Path(p).exists() and not args.force:
            print(f"necviz: error: {p} exists (use --force to replace it)", file=sys.stderr)
            return 2
    inputs = {Path(d).resolve() for d in args.dirs}
    for p in (args.out, args.json, args.rows):
        if p and Path(p).resolve() in inputs:
            print(f"necviz: error: {p} is an input; choose another output", file=sys.stderr)
            return 2
    metrics = args.metric or ["saturated_frames_50", "saturated_frames_10"]
    try:
        parts, data = [], {}
        every = load_rows(args.dirs, [])
        per_controller: dict[str, int] = defaultdict(int)
        for r in every:
            per_controller[r["controller"]] += 1
        data["runs"] = {"total": len(every), "controllers": dict(sorted(per_controller.items()))}
        for metric in metrics:
            text, d = build(args.dirs, metric)
            parts.append(text)
            data[metric] = d
        if args.rows:
            write_rows_csv(args.rows, load_rows(args.dirs, metrics), metrics)
    except NecvizError as e:
        print(f"necviz: error: {' '.join(str(e).split())}", file=sys.stderr)
        return 2
    text = "\n".join(parts)
    print(text)
    if args.out:
        Path(args.out).write_text(text + "\n", encoding="utf-8")
    if args.json:
        cmd = "python benchmarks/events_table.py " + " ".join(argv if argv is not None else sys.argv[1:])
        out = {"command": cmd, "markdown": text, **data}  # the tables as printed, for docs/results.md
        Path(args.json).write_text(json.dumps(out, indent=1, default=float), encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
