"""The evaluation's scripts: the tuning budget and rule (benchmarks/tuning.py) and the paired tables of
what the events add (benchmarks/events_table.py), on synthetic numbers whose answer is known."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import t as student_t

pytestmark = pytest.mark.slow  # closed loops, subprocesses or Dask: `pytest -m 'not slow'` leaves them out

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


def _load(name):
    spec = importlib.util.spec_from_file_location(name, BENCH / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


tuning = _load("tuning")
events_table = _load("events_table")


def row(ctrl, scene, seed, value, ceiling=12e6, latency=1000.0, transition=None, metric="saturated_frames_50"):
    return {
        "scene": scene,
        "family": events_table.family(scene),
        "seed": seed,
        "controller": ctrl,
        "ceiling": ceiling,
        "latency_us": latency,
        "transition_ms": transition,
        metric: value,
    }


# -- tuning -----------------------------------------------------------------------------------------
def test_every_tuned_controller_gets_the_same_budget_with_its_published_setting_among_the_variants():
    v = tuning.variants()
    assert set(v) == {"nec", "navid", "shim", "begin"}
    for name, variants in v.items():
        assert len(variants) == tuning.VARIANTS == 20, name
        assert tuning.PUBLISHED[name] in variants, name
    assert v["navid"][tuning.PUBLISHED["navid"]] == {"ev_per_unit": 0.01, "target_msv": 2.5}
    assert v["begin"][tuning.PUBLISHED["begin"]] == {"feedback_gain": 1.5, "ev_range": 2.0}
    # the NEC candidates are benchmarks/metering.py's, and its current default is one of them
    assert v["nec"]["median_100_esc04"] == {
        "metering": "median",
        "goal_mode": "paper",
        "escape": True,
        "edge_margin": 0.4,
        "goal": 100,
    }
    assert set(tuning.NOT_TUNED) == {"builtin", "fixed"}


def test_the_rule_is_least_regret_then_slightly_saturated_then_valid_fraction():
    def cell(s50, s10, tv):
        return {
            "saturated_frames_50": {"mean": s50},
            "saturated_frames_10": {"mean": s10},
            "true_valid_fraction_mean": {"mean": tv},
        }

    table = {
        "a": {"x@v0": cell(2, 5, 0.9), "x@v1": cell(1, 9, 0.8), "x@v2": cell(1, 6, 0.7), "x@v3": cell(1, 6, 0.95)},
        "b": {"x@v0": cell(0, 1, 0.9), "x@v1": cell(1, 1, 0.9), "x@v2": cell(0, 1, 0.9), "x@v3": cell(0, 1, 0.9)},
    }
    ranking = tuning.choose(table, ["x@v0", "x@v1", "x@v2", "x@v3"])
    # regrets: v0 = 1 + 0, v1 = 0 + 1, v2 = v3 = 0; v2 and v3 tie on > 10 % (7): v3 has the higher valid
    # fraction; v0 and v1 tie on regret (1): v0 has fewer > 10 % frames (6 against 10)
    assert [r[3] for r in ranking] == ["x@v3", "x@v2", "x@v0", "x@v1"]
    assert ranking[0][0] == 0 and ranking[-1][0] == 1


# -- the events table -------------------------------------------------------------------------------
def test_nec_minus_nec_frames_is_paired_by_seed_with_a_student_t_interval_clustered_by_scene():
    rows = []
    nec = {"tunnel_exit_1000": [0, 1, 0, 0], "tunnel_exit_1001": [1, 1, 2, 0]}
    frames = {"tunnel_exit_1000": [2, 2, 3, 1], "tunnel_exit_1001": [2, 3, 2, 2]}
    for scene in nec:
        for seed in range(4):
            rows.append(row("nec", scene, 100 + seed, nec[scene][seed]))
            rows.append(row("nec-frames", scene, 100 + seed, frames[scene][seed]))
    rows.append(row("nec", "tunnel_exit_1000", 200, 5))  # a seed without its pair is left out
    idx = events_table.index(rows)
    by = events_table.paired(idx, "nec", "nec-frames", "saturated_frames_50", events_table.default_condition)
    scenes, fams = events_table.diff_cells(by)
    d = np.array([-2, -1, -3, -1], float)  # tunnel_exit_1000, per seed
    half = student_t.ppf(0.975, 3) * d.std(ddof=1) / 2.0
    a, b, m, ci, n = scenes["tunnel_exit_1000"]
    assert (a, b, n) == (0.25, 2.0, 4) and m == pytest.approx(-1.75) and ci == pytest.approx(half)
    # the family: the interval is over its scenes' mean differences (-1.75, -1.25), not over its 8 pairs
    means = np.array([-1.75, -1.25])
    _, _, m, ci, n = fams["tunnel_exit"]
    assert n == 2 and m == pytest.approx(means.mean())
    assert ci == pytest.approx(student_t.ppf(0.975, 1) * means.std(ddof=1) / math.sqrt(2))
    # in how many scenes the effect lives, and a bootstrap that resamples whole scenes
    counts = events_table.scene_counts(by)
    assert counts["scenes"] == 2 and counts["negative"] == 2 and counts["zero_pairs"] == 1 and counts["pairs"] == 8
    lo, hi = events_table.scene_bootstrap(by)
    assert -1.75 <= lo <= hi <= -1.25  # only the two scenes' means can be drawn


def test_a_scene_that_always_differs_by_zero_counts_as_no_effect():
    by = {"a": [(0, -2.0, 0, 2), (1, -2.0, 0, 2)], "b": [(0, 0.0, 1, 1), (1, 0.0, 1, 1)], "c": [(0, 0.0, 0, 0)]}
    counts = events_table.scene_counts(by)
    assert (counts["scenes"], counts["negative"], counts["zero"], counts["zero_pairs"]) == (3, 1, 2, 3)
    m, ci, n = events_table.clustered(by)
    assert n == 3 and m == pytest.approx(-2.0 / 3)  # one scene of three carries the effect: not significant
    assert ci > abs(m)


def test_nec_at_any_ceiling_pairs_with_nec_frames_but_latency_must_match():
    rows = [
        row("nec", "static_lab_1300", 100, 1, ceiling=6e6),
        row("nec", "static_lab_1300", 100, 0, ceiling="none"),
        row("nec-frames", "static_lab_1300", 100, 3),  # at the default 12 Mev/s: the same run at any ceiling
        row("nec", "static_lab_1300", 100, 2, latency=5000.0),
        row("nec-frames", "static_lab_1300", 100, 4, latency=5000.0),
    ]
    idx = events_table.index(rows)
    for ceiling, want in ((6e6, -2.0), ("none", -3.0)):
        by = events_table.paired(
            idx, "nec", "nec-frames", "saturated_frames_50", lambda r, c=ceiling: r["ceiling"] == c, b_any_ceiling=True
        )
        assert [x[1] for x in by["static_lab_1300"]] == [want]
    by = events_table.paired(idx, "nec", "nec-frames", "saturated_frames_50", lambda r: r["latency_us"] == 5000.0)
    assert [x[1] for x in by["static_lab_1300"]] == [-2.0]  # against nec-frames at 5 ms, not at 1 ms
    # without the ceiling exemption a missing nec-frames ceiling is no pair
    by = events_table.paired(idx, "nec", "nec-frames", "saturated_frames_50", lambda r: r["ceiling"] == 6e6)
    assert not by


def test_the_tables_name_each_rung_and_each_tuned_baseline():
    rows = []
    for seed in range(3):
        for k, rung in enumerate(events_table.LADDER):
            rows.append(row(rung, "flicker_1200", seed, 10 - 2 * k))
        rows += [row("navid", "flicker_1200", seed, 4), row("navid-tuned", "flicker_1200", seed, 3)]
        rows += [row("nec-frames", "flicker_1200", seed, 3)]
    idx = events_table.index(rows)
    out, data = [], {}
    events_table.section_ladder(idx, "saturated_frames_50", out, data)
    text = "\n".join(out)
    assert "`nec@escape` + escape rule" in text and "`nec-paper` (the paper)" in text
    assert data["ladder"]["nec@bound"]["flicker"]["step"][:2] == [-2.0, 0.0]
    out, data = [], {}
    events_table.section_baselines(idx, "saturated_frames_50", out, data)
    assert "| `navid-tuned` | 3.00 (-1.00 (1 scene)) |" in "\n".join(out)
    out, data = [], {}
    events_table.section_events(idx, "saturated_frames_50", out, data)
    last = 10 - 2 * (len(events_table.LADDER) - 1)  # nec, the ladder's last rung
    assert data["events"]["families"]["flicker"][2] == pytest.approx(last - 3.0)  # nec - nec-frames


def test_nec_against_each_tuned_baseline_is_paired_by_seed_and_clustered_by_scene():
    rows = []
    for scene, nec, shim in (
        ("flicker_5200", [1, 1], [3, 5]),
        ("flicker_5201", [2, 0], [2, 0]),
        ("static_lab_5300", [0, 0], [0, 1]),
    ):
        for seed in (300, 301):
            rows += [row("nec", scene, seed, nec[seed - 300]), row("shim-tuned", scene, seed, shim[seed - 300])]
    rows.append(row("shim-tuned", "flicker_5202", 300, 9))  # no NEC run beside it: no pair
    out, data = [], {}
    events_table.section_versus(events_table.index(rows), "saturated_frames_50", out, data)
    rec = data["versus"]["shim-tuned"]
    # per scene: flicker_5200 -3, flicker_5201 0, static_lab_5300 -0.5; the flicker family over its 2 scenes
    m, ci, n = rec["flicker"]
    assert n == 2 and m == pytest.approx(-1.5)
    assert ci == pytest.approx(student_t.ppf(0.975, 1) * np.std([-3.0, 0.0], ddof=1) / math.sqrt(2))
    m, ci, n = rec["all"]
    assert n == 3 and m == pytest.approx(np.mean([-2, -4, 0, 0, 0, -1]))
    assert rec["scene_counts"]["negative"] == 2 and rec["scene_counts"]["zero"] == 1
    assert "| `shim-tuned` |" in "\n".join(out) and "2 / 0 |" in "\n".join(out)


def test_a_rows_file_gives_back_the_rows_and_the_same_tables(tmp_path):
    """The committed rows file stands in for the sweep folders: the same rows, so the same numbers."""
    rows = []
    for seed in range(100, 104):
        rows.append(row("nec", "tunnel_exit_1000", seed, seed % 2, ceiling=6e6))
        rows.append(row("nec", "tunnel_exit_1000", seed, 0.0, ceiling="none"))
        rows.append(row("nec", "tunnel_exit_1000", seed, 1.0, transition=40))
        rows.append(row("nec-frames", "tunnel_exit_1000", seed, 2.0 + seed % 3, latency=200.0))
        rows.append(row("nec-frames", "tunnel_exit_1000", seed, math.nan))
    path = tmp_path / "rows.csv"
    events_table.write_rows_csv(path, rows, ["saturated_frames_50"])
    back = events_table.read_rows_csv(path, ["saturated_frames_50"])
    key = lambda r: tuple(str(r[k]) for k in events_table.ROW_KEYS)  # noqa: E731
    for a, b in zip(sorted(rows, key=key), sorted(back, key=key), strict=True):
        for k in events_table.ROW_KEYS:
            assert a[k] == b[k] and type(a[k]) is type(b[k]), k
        v, w = a["saturated_frames_50"], b["saturated_frames_50"]
        assert (math.isnan(v) and w is None) or v == w
    with pytest.raises(Exception, match="without saturated_frames_10"):
        events_table.read_rows_csv(path, ["saturated_frames_10"])
    # a damaged line is named, not a traceback
    bad = tmp_path / "bad.csv"
    bad.write_text(path.read_text().replace("tunnel_exit_1000,tunnel_exit,100,", "tunnel_exit_1000,tunnel_exit,x,", 1))
    with pytest.raises(Exception, match=r"bad.csv, line \d+: not a row"):
        events_table.read_rows_csv(bad, ["saturated_frames_50"])
    assert events_table.main([str(bad)]) == 2
    # the script refuses to write its rows over an input
    assert events_table.main([str(path), "--rows", str(path), "--force"]) == 2


def test_the_sealed_criteria_are_judged_only_on_a_complete_run_and_say_which_failed(tmp_path, monkeypatch):
    """results_page's sealed section: no figure until every run is in; then each criterion met or not,
    as the numbers say (here NEC wins at > 50 %, loses to nec-frames in one family at > 10 %)."""
    metrics = ["saturated_frames_50", "saturated_frames_10", "true_valid_fraction_mean"]
    rows = []
    for scene in ("flicker_5200", "flicker_5201", "static_lab_5300", "static_lab_5301"):
        for seed in (300, 301):
            flick = scene.startswith("flicker")
            vals = {
                "nec": (0, 3 if flick else 0, 0.9),
                "nec-frames": (2 + seed % 2, 1 if flick else 2, 0.85),
                "navid-tuned": (1, 2, 0.8),
                "shim-tuned": (4, 5, 0.7),
            }
            for ctrl, v in vals.items():
                r = row(ctrl, scene, seed, v[0])
                r.update(dict(zip(metrics, v, strict=True)))
                rows.append(r)
    path = tmp_path / "sealed_rows.csv"
    events_table.write_rows_csv(path, rows, metrics)
    out = tmp_path / "sealed.json"
    args = [str(path), *[x for m in metrics for x in ("--metric", m)], "--json", str(out)]
    assert events_table.main(args) == 0
    import json

    page = _load("results_page")
    d = json.loads(out.read_text())
    assert d["runs"]["total"] == 32
    monkeypatch.setattr(page, "sealed_expected", lambda name="sealed": 33)
    assert "32 of its 33 runs" in page.r_sealed(d) and "±" not in page.r_sealed(d)
    monkeypatch.setattr(page, "sealed_expected", lambda name="sealed": 32)
    verdicts = {c.split(" (")[0]: ok for c, _, ok in page.sealed_verdicts(d)}
    assert len(verdicts) == 4
    assert verdicts["NEC − `nec-frames` < 0 at > 50 % clipped, the scene-clustered 95 % CI excluding 0"]
    assert not verdicts["at > 10 % clipped, NEC − `nec-frames` ≤ 0 in every family"]  # flicker: +2
    assert verdicts["NEC no worse than the best tuned baseline in frames > 10 % clipped"]  # against navid-tuned
    assert verdicts["NEC no worse than the best tuned baseline in true-valid fraction"]
    text = page.r_sealed(d)
    assert "**not met**" in text and "`navid-tuned`" in text
    head = page.render_sealed_headline(d)
    assert "3 of the 4 criteria" in head and "not met: at > 10 % clipped" in head
    # the newest complete sealed set makes the README's headline, linking its own section; an incomplete one is silent
    head2 = page.render_headline({"sealed": d, "sealed2": d})
    assert head2.startswith("On the second sealed test set")
    assert "The first sealed set (seeds 300..309" in head2 and "met 3 of the 4 (not met: at > 10 % clipped" in head2
    assert f"docs/results.md#{page.github_anchor(page.SEALED_TITLES['sealed2'])})" in head2
    assert page.github_anchor("The first sealed evaluation, spent (25 scenes, seeds 300..309)") == (
        "the-first-sealed-evaluation-spent-25-scenes-seeds-300309"
    )
    monkeypatch.setattr(page, "sealed_expected", lambda name="sealed": 32 if name == "sealed" else 1250)
    assert page.render_headline({"sealed": d, "sealed2": d}).startswith("On the sealed test set (")
