"""The DVS sweep (benchmarks/dvs_sweep.py): run specs that set the DVS biases at scene start, the sweep's
summary and its results-page section."""

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _load(name):
    import sys

    sys.path.insert(0, str(ROOT / "benchmarks"))
    spec = importlib.util.spec_from_file_location(name, ROOT / "benchmarks" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_a_run_spec_sets_the_biases_at_scene_start_and_without_them_is_unchanged():
    """``"dvs": []`` is the run without the key, to the last number; ``c_on = c_off = 0.15`` gives more events and
    P-TEDI's thresholds at 0.15 from the first packet (the stream starts at those biases)."""
    from necviz.runs import run_spec

    spec = {"scenario": "static_lab", "seed": 0, "duration_s": 0.3, "controllers": ["nec"], "sift": False}
    plain = run_spec(spec, threads=False)["results"]["nec"]
    assert run_spec({**spec, "dvs": []}, threads=False)["results"]["nec"] == plain

    sweep = _load("dvs_sweep")
    low = sweep.run("static_lab", 0, (("c_on", "0.15"), ("c_off", "0.15")), 0.3)
    base = sweep.run("static_lab", 0, (), 0.3)
    assert low["lanes"]["nec"]["ptedi"]["c_on"] == pytest.approx(0.15, rel=0.01)
    assert base["lanes"]["nec"]["ptedi"]["c_on"] == pytest.approx(0.2573, rel=0.01)  # the shipped profile's
    assert low["crossings"] > 1.5 * base["crossings"] and low["events"] > base["events"]
    assert base["lanes"]["nec"]["saturated_frames_10"] == plain["saturated_frames_10"]  # the same closed loop


def test_the_summary_pairs_each_setting_with_the_default_and_the_page_renders_it():
    sweep = _load("dvs_sweep")
    page = _load("results_page")
    labels = list(sweep.settings())
    default = "c=default, refr=default"
    assert default in labels and len(labels) == 6
    assert sweep.settings()["c=0.15, refr=400 us"] == (("c_on", "0.15"), ("c_off", "0.15"), ("refractory_us", "400"))
    runs = []
    for lab in labels:
        for scene in ("static_lab", "benchmarks/training/flicker_deep_100.toml"):
            for seed in (0, 1):
                worse = 2 if lab.startswith("c=0.15") and "flicker" in scene else 0
                lanes = {
                    ln: {
                        "saturated_frames_50": 1 + worse,
                        "saturated_frames_10": 3 + worse + (ln == "nec-frames"),
                        "true_valid_fraction_mean": 0.8,
                        "prediction_error_rmse": 0.1,
                        "ptedi": {"c_on": 0.15, "c_off": 0.15},
                    }
                    for ln in sweep.LANES
                }
                runs.append(
                    {
                        "setting": lab,
                        "scenario": scene,
                        "seed": seed,
                        "lanes": lanes,
                        "events": 1_000_000 * (2 if lab.startswith("c=0.15") else 1),
                        "crossings": 3_000_000,
                        "lost_refractory": 10,
                        "lost_bus_ceiling": 5_000_000 if "flicker" in scene else 0,
                    }
                )
    table = sweep.summarise(runs, labels, default)
    low = table["c=0.15, refr=default"]
    assert low["runs"] == 4 and low["saturated_frames_10"]["nec - nec at default"][0] == 1.0
    assert low["saturated_frames_10"]["nec - nec-frames"] == (-1.0, 0.0)
    assert low["events_vs_default"][0] == 2.0
    assert low["per_scene_saturated_frames_10_nec"] == {"static_lab": 3.0, "flicker_deep_100": 5.0}
    assert table[default]["saturated_frames_10"]["nec - nec at default"] == (0.0, 0.0)
    text = page.r_dvs_sweep(
        {"command": "x", "seeds": [0, 1], "lanes": list(sweep.LANES), "table": table, "default": default}
    )
    assert "| c=0.15, refr=default | 0.150 / 0.150 |" in text and "| 2.00 (x2.00) |" in text
    assert "| flicker_deep_100 |" in text and "5.0 (5.0 M)" in text
    assert "2 scenes" in text and "24 closed-loop runs" in text
