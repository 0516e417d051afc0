"""What the events add on a real recording (issue 20, item 9): P-TEDI's next-frame error beside predictors
that see frames only, as a skill score, in the replay summary, its JSON and the dashboard."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from rrd_read import Rrd

from necviz import schema as S
from necviz.commands.cli import main
from necviz.core.prediction_skill import SkillTracker, skill_from_columns

pytestmark = pytest.mark.slow  # closed loops, subprocesses or Dask: `pytest -m 'not slow'` leaves them out

SAMPLE = Path(__file__).resolve().parents[2] / "shared" / "data" / "davis346_sample.aedat4"
NAN = math.nan


def test_skill_on_a_hand_made_sequence():
    # ln P̄ rises by 0.125 per 20 ms frame (a steady drift; dyadic values, so the arithmetic is exact);
    # frame 2 is unusable (saturated)
    t = [10_000, 30_000, 50_000, 70_000, 90_000, 110_000]
    m = [1.0, 1.125, NAN, 1.375, 1.5, 1.625]
    e = [NAN, 0.0625, NAN, -0.03125, 0.015625, 0.0]  # P-TEDI's errors
    tr = SkillTracker()
    out = [tr.update(mi, ei, ti) for mi, ei, ti in zip(m, e, t, strict=True)]
    pers = [o[0] for o in out]
    # persistence: the last usable frame (frame 3, after the unusable frame 2, is predicted by frame 1)
    np.testing.assert_array_equal(pers[1:], [-0.125, NAN, -0.25, -0.125, -0.125])
    assert math.isnan(pers[0])
    # trend: the line through the last two usable frames is exact on a steady drift
    trend = [o[1] for o in out]
    assert all(math.isnan(x) for x in trend[:3]) and trend[3:] == [0.0, 0.0, 0.0]
    s = tr.summary()
    p = s["persistence"]  # frames 1, 3, 4, 5 have both predictions
    sse_p, sse_q = 0.0625**2 + 0.03125**2 + 0.015625**2 + 0.0, 0.125**2 + 0.25**2 + 0.125**2 + 0.125**2
    assert p["frames"] == 4 and p["skill"] == pytest.approx(1 - sse_p / sse_q)
    assert p["rmse_ptedi"] == pytest.approx(math.sqrt(sse_p / 4)) and p["rmse_reference"] == pytest.approx(
        math.sqrt(sse_q / 4)
    )
    assert out[-1][2] == pytest.approx(p["skill"])  # the running score ends at the summary's
    assert s["trend"]["frames"] == 3 and s["trend"]["skill"] is None  # the trend is exact: the score is undefined
    assert skill_from_columns(m, e, t) == s
    empty = SkillTracker().summary()["persistence"]
    assert empty == {"frames": 0, "rmse_ptedi": None, "rmse_reference": None, "skill": None}


@pytest.mark.skipif(not SAMPLE.exists(), reason="real sample ../shared/data/davis346_sample.aedat4 not present")
def test_replay_summary_holds_the_persistence_comparison(tmp_path, capsys):
    out, rrd = tmp_path / "r.json", tmp_path / "r.rrd"
    assert main(["replay", str(SAMPLE), "--json", str(out), "--save", str(rrd)]) == 0
    text = capsys.readouterr().out
    assert "against same as the last frame (frames only)" in text and "skill score" in text
    data = json.loads(out.read_text())
    rows = data["frames_detail"]
    # independent computation from the per-frame values: persistence = the last usable frame's ln P̄
    last, err_p, err_q = None, [], []
    for r in rows:
        m, pred = r["measured_log_irradiance"], r["predicted_log_irradiance"]
        if m is None:
            continue
        if last is not None and pred is not None:
            err_p.append(pred - m)
            err_q.append(last - m)
        last = m
    assert len(err_p) >= 2
    sk = data["prediction_skill"]["persistence"]
    mse_p, mse_q = np.mean(np.square(err_p)), np.mean(np.square(err_q))
    assert sk["frames"] == len(err_p)
    assert sk["skill"] == pytest.approx(1 - mse_p / mse_q, rel=1e-9)
    assert sk["rmse_ptedi"] == pytest.approx(math.sqrt(mse_p)) and sk["rmse_reference"] == pytest.approx(
        math.sqrt(mse_q)
    )
    assert f"{sk['skill']:+.3f}" in text
    # the per-frame persistence errors are in the JSON and on the dashboard
    assert [r["persistence_error"] for r in rows if r["persistence_error"] is not None] == pytest.approx(err_q)
    r = Rrd(rrd)
    assert r.rows[S.path("camera", S.PERSISTENCE_ERROR)] == len(err_q)
    assert r.rows[S.path("camera", S.PREDICTION_SKILL)] >= len(err_p)
