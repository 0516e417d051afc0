"""DVS biases change the emulated stream: each control's effect on the events the driver decodes (issue 29)."""

import numpy as np
import pytest

from necviz.core.biases import BiasModel, DvsSettings, DvsState
from necviz.core.errors import ParameterError
from necviz.core.events import EVENT_DTYPE, EventBatch
from necviz.core.sensor import SensorGeometry
from necviz.drivers.davis import EmulatedDavis346, EmulatorOptions, open_camera
from necviz.drivers.davis import protocol as P
from necviz.drivers.sim.dvs import DvsParams, EventSimulator, params_for_biases

SMALL = SensorGeometry(64, 48)
REF = DvsSettings(0.26, 0.24, 100.0, 300.0)  # the simulated DAVIS346 at libcaer's default biases


def emulated(controls=(), duration_s=0.3, **scene):
    """Events (t, p) the driver decodes from an emulated camera whose DVS was set with ``controls`` before streaming."""
    be = EmulatedDavis346(
        EmulatorOptions(scenario="static_lab", duration_s=duration_s, sensor=SMALL, scenario_params=scene)
    )
    cam = open_camera("emulated", backend=be)
    st = DvsState(BiasModel(cam.dvs_family, REF))
    for k, v in controls:
        ch = st.request(k, v)
        cam.set_dvs_biases(ch.words())
        st.apply(ch)
    ev = np.concatenate([p.events for p in cam if isinstance(p, EventBatch)])
    return ev, be


# one slow light ramp (+10 dB over 100 ms at 0.1 s): no refractory or bus limit, so events count crossings
SLOW = {"steps": [(0.1, 10.0)], "ramp_ms": 100.0, "change_jitter_ms": 0.0}
# one instantaneous +40 dB step: a pixel crosses many thresholds at once (refractory, bandwidth show)
FAST = {"steps": [(0.1, 40.0)], "ramp_ms": 0.0, "change_jitter_ms": 0.0}


def test_the_driver_writes_the_words_and_the_emulated_pixel_follows():
    ev, be = emulated([("c_on", 0.15), ("c_off", 0.15), ("refractory_us", 50.0), ("bandwidth_hz", 600.0)])
    st = DvsState(BiasModel("DAVIS346", REF))
    on = st.request("c_on", 0.15).words()
    assert all(be.reg(P.BIAS.MODULE, a) == w for a, w in on.items())  # the 0xC2 request reached the registers
    p = be._rig.dvs_params
    assert p.c_on == pytest.approx(0.15, rel=0.01) and p.c_off == pytest.approx(0.15, rel=0.01)
    assert p.refractory_us == pytest.approx(50.0, rel=0.01) and p.cutoff_hz == pytest.approx(600.0, rel=0.02)


def test_lower_thresholds_give_proportionally_more_events():
    base, _ = emulated(**SLOW)
    low, _ = emulated([("c_on", 0.13), ("c_off", 0.12)], **SLOW)
    ratio = len(low) / len(base)
    assert 1.7 < ratio < 2.3  # crossings scale with 1/c: 0.26/0.13 = 2
    hi, _ = emulated([("c_on", 0.4)], **SLOW)  # a brightening ramp: ON events, fewer with a higher ON threshold
    assert (hi["p"] > 0).sum() < 0.8 * (base["p"] > 0).sum()


def test_refractory_period_drops_events_of_a_fast_step():
    base, _ = emulated(**FAST)
    long, _ = emulated([("refractory_us", 2000.0)], **FAST)
    short, _ = emulated([("refractory_us", 5.0)], **FAST)
    assert len(long) < 0.7 * len(base) < 0.7 * len(short)


def test_bandwidth_spreads_a_step_over_time():
    def spread(ev):
        t = ev["t"][ev["t"] > 95_000]
        return np.percentile(t, 90) - np.percentile(t, 10)

    base, _ = emulated([("refractory_us", 5.0)], **FAST)
    slow, _ = emulated([("refractory_us", 5.0), ("bandwidth_hz", 30.0)], **FAST)
    assert spread(slow) > 3 * spread(base)


def test_leak_noise_rises_as_the_threshold_falls():
    # no light change: only the leak (background activity) and shot noise
    base, _ = emulated(duration_s=1.0, steps=[], change_jitter_ms=0.0)
    low, _ = emulated([("c_on", 0.13)], duration_s=1.0, steps=[], change_jitter_ms=0.0)
    assert len(low) > 1.5 * len(base) > 0


def test_retune_mid_run_is_timed_and_refused_from_the_cache():
    sim = EventSimulator(SMALL, DvsParams(), seed=1)
    img = np.full(SMALL.shape, 5.0, np.float32)
    sim.reset(img, 0)
    sim.step(img + 1.0, 1000)
    n_before = sim.crossings
    sim.retune(DvsParams().replace(c_on=0.13))
    assert sim.retuned_us is None  # not before the next step
    sim.step(img + 2.0, 2000)
    assert sim.retuned_us == 1000
    assert sim.crossings - n_before > 1.6 * n_before  # the same +1 ln now crosses twice as many thresholds
    with pytest.raises(ParameterError):
        sim.retune(DvsParams().replace(sigma_threshold=0.05))


def test_params_for_biases_is_identity_at_defaults_and_keeps_leak_drift():
    from necviz.core.biases import DvsBiases

    base = DvsParams()
    assert params_for_biases(base, DvsBiases.defaults()).as_dict() == pytest.approx(base.as_dict())
    b = DvsState(BiasModel("DAVIS346", REF)).request("c_on", 0.13).biases
    p = params_for_biases(base, b)
    assert p.leak_hz * p.c_on == pytest.approx(base.leak_hz * base.c_on)  # drift (ln per s) unchanged


# -- the pipeline: tuning lines, P-TEDI following at the packet where the change shows, the summary ----------


def sim_pipeline(duration_us=300_000, **scene):
    from necviz.drivers.sim.rig import RigOptions, SimRig
    from necviz.drivers.sim.scenes import make_scenario
    from necviz.pipeline import Lane, Pipeline
    from necviz.runs import make_controller

    sc = make_scenario("static_lab", sensor=SMALL, duration_us=duration_us, seed=0, **scene)
    rig = SimRig(sc, ["camera"], seed=0, options=RigOptions(threads=True))
    lane = Lane("camera", make_controller("nec", sensor=SMALL, limits=rig.camera_info.limits))
    return rig, Pipeline(rig, [lane], warm_up=False)


def record_a_bias_change(path):
    """A simulated run recorded to ``path`` (.necrec) with one live change, c_on -> 0.13 at the 20th batch."""
    from dvs_recording import record_with_dvs_changes

    rig, pipe = sim_pipeline(**SLOW)
    record_with_dvs_changes(pipe, path, SMALL, [("c_on", 0.13)], lambda n, batch: n == 20)
    return rig, pipe


def test_tuning_lines_for_the_dvs():
    from necviz.dashboard.tuning import parse

    c = parse("dvs.c_on = 0.2")
    assert (c.kind, c.key, c.value) == ("dvs", "c_on", "0.2")
    c = parse("set bias.DiffBn 4/39")
    assert (c.kind, c.key, c.value) == ("dvs", "bias.DiffBn", "4/39")
    assert parse("nec.c_on = 0.2").kind == "set"  # a lane's P-TEDI threshold is still its own key


def test_help_lists_the_dvs_controls_only_where_the_source_has_them():
    from necviz.dashboard.tuning import help_text, keys
    from necviz.pipeline import Lane, Pipeline

    _, pipe = sim_pipeline()
    assert {"dvs.c_on", "dvs.refractory_us", "dvs.ba_filter_us", "bias.NAME"} <= set(keys(pipe))
    assert "dvs.bandwidth_hz" in help_text(pipe)

    from necviz.drivers.source import Source

    class Replay(Source):  # a recording: no DVS to set
        from necviz.drivers.source import CameraInfo

        cameras = ("camera",)
        sensor = SMALL
        camera_info = CameraInfo()

        def packets(self):
            return iter(())

        def set_exposure(self, *a, **k):
            pass

    lane = pipe.lanes["camera"]
    rec = Pipeline(Replay(), [Lane("camera", lane.controller)], warm_up=False)
    assert not any(k.startswith("dvs.") for k in keys(rec))
    fut = rec.tune_dvs("c_on", 0.2)
    rec._apply_changes()
    with pytest.raises(ParameterError, match="takes no DVS bias changes"):
        fut.result(0)


def test_ptedi_follows_at_the_batch_where_the_change_shows():
    from necviz.pipeline import Observer, _estimator

    rig, pipe = sim_pipeline(**SLOW)
    est = _estimator(pipe.lanes["camera"])
    c0 = est.params.c_on
    seen, futs = [], []

    class Watch(Observer):  # called after the lanes took each batch
        def events(self, batch):
            seen.append((int(batch["t"][-1]), est.params.c_on))
            if len(seen) == 20:  # mid-run: queued, applied between two packets
                futs.append(pipe.tune_dvs("c_on", 0.13))

    pipe.observers.append(Watch())
    pipe.run()
    stats = pipe.finish()
    assert "c_on = 0.13" in futs[0].result(0)
    # the request is read against the lane's profile: P-TEDI now uses 0.13 (quantised), the simulator 0.13 x 0.26/c0
    assert est.params.c_on == pytest.approx(0.13, rel=0.01)
    assert rig.dvs_params.c_on == pytest.approx(0.13 * 0.26 / c0, rel=0.01)
    t = pipe.dvs.followed_from_us
    assert t is not None and t > seen[19][0]  # the DVS worker applied it at a later step
    old = [last for last, c in seen if c == c0]
    new = [last for last, c in seen if c != c0]
    assert old and new and max(old) < t <= min(new)  # exactly the first batch holding events after the change
    assert stats["lanes"]["camera"]["ptedi"] == {"c_on": est.params.c_on, "c_off": est.params.c_off}
    assert stats["dvs"]["changes"][0]["key"] == "c_on"


def test_a_refused_change_changes_nothing():
    from necviz.dashboard.tuning import parse
    from necviz.pipeline import _estimator

    rig, pipe = sim_pipeline()
    est = _estimator(pipe.lanes["camera"])
    before = (est.params, rig.dvs_params)
    for line, text in (
        ("dvs.c_on = -3", "positive number"),
        ("dvs.c_on = 9", "nearest reachable"),
        ("bias.X = 1/2", "no coarse/fine"),
    ):
        fut = pipe.tune_dvs(parse(line).key, parse(line).value)
        pipe._apply_changes()
        with pytest.raises(ParameterError, match=text):
            fut.result(0)
    assert (est.params, rig.dvs_params) == before
    assert pipe.dvs.state is not None and pipe.dvs.state.biases == pipe.dvs.state.model.defaults


def test_a_bias_change_is_in_the_rrd_timeline_and_the_native_recording(tmp_path):
    import sys
    from pathlib import Path

    import rerun as rr

    sys.path.insert(0, str(Path(__file__).parent))
    from rrd_read import Rrd

    from necviz import schema as S
    from necviz.dashboard.sink import RerunSink, SinkOptions
    from necviz.drivers.recordings import Recorder, open_recording
    from necviz.pipeline import RecorderObserver

    rig, pipe = sim_pipeline(duration_us=100_000)
    rec = rr.RecordingStream("necviz-test")
    rec.save(str(tmp_path / "t.rrd"))
    sink = RerunSink(rec, ["camera"], SMALL.height, SMALL.width, SinkOptions(lossless=True))
    recorder = Recorder(tmp_path / "t.necrec", sensor=SMALL, properties={})
    pipe.observers += [sink, RecorderObserver(recorder, "camera")]
    fut = pipe.tune_dvs("c_off", 0.12)  # before the first packet: written at once, noted at the first packet
    pipe.run().finish()
    rr.disconnect(rec)
    assert "c_off = 0.12" in fut.result(0)
    r = Rrd(tmp_path / "t.rrd")
    t, v = r.series(f"{S.DVS}/c_off")
    assert v[-1] == pytest.approx(0.12, rel=0.01)
    _, v = r.series(S.path("camera", S.PTEDI_C_OFF))
    assert v[-1] == pytest.approx(0.12, rel=0.01)
    notes = [n["dvs"] for _, n in open_recording(tmp_path / "t.necrec").annotations if "dvs" in n]
    assert notes[0]["key"] == "c_off" and notes[0]["c_off"] == pytest.approx(0.12, rel=0.01)
    assert notes[0]["words"] == {"12": DvsState(BiasModel("DAVIS346", REF)).request("c_off", 0.12).words()[12]}


def test_emulated_camera_mid_run_ptedi_follows_where_the_stream_changes():
    """The whole live path: the driver writes the words mid-run, the emulated pixel changes at some later device
    time (the reader reads ahead), and P-TEDI follows at exactly the first batch from that time on."""
    from necviz.pipeline import Lane, Observer, Pipeline, _estimator
    from necviz.runs import make_controller

    be = EmulatedDavis346(EmulatorOptions(scenario="static_lab", duration_s=0.4, sensor=SMALL, scenario_params=SLOW))
    cam = open_camera("emulated", backend=be)
    lane = Lane("camera", make_controller("nec", sensor=cam.sensor, limits=cam.limits))
    pipe = Pipeline(cam, [lane], warm_up=False)
    est = _estimator(lane)
    c0 = est.params.c_on
    seen, futs = [], []

    class Watch(Observer):
        def events(self, batch):
            seen.append((int(batch["t"][0]), int(batch["t"][-1]), est.params.c_on))
            if len(seen) == 30:
                futs.append(pipe.tune_dvs("c_on", 0.13))

    pipe.observers.append(Watch())
    pipe.run()
    pipe.finish()
    assert "c_on = 0.13" in futs[0].result(0)
    assert be.reg(P.BIAS.MODULE, 11) == DvsState(BiasModel("DAVIS346", REF)).request("c_on", 0.13).words()[11]
    t = pipe.dvs.followed_from_us
    old = [last for _, last, c in seen if c == c0]
    new = [last for _, last, c in seen if c != c0]
    assert t is not None and old and new and max(old) < t <= min(new)
    assert est.params.c_on == pytest.approx(0.13, rel=0.01)
    # the emulated camera's pixel at the default biases is its simulator's, which the request is read against
    ref = pipe.dvs.state.model.ref
    assert (ref.refractory_us, ref.bandwidth_hz) == (DvsParams().refractory_us, DvsParams().cutoff_hz)


def filtered(controls, load=0.0, **scene):
    be = EmulatedDavis346(
        EmulatorOptions(
            scenario="static_lab",
            duration_s=0.3,
            sensor=SMALL,
            scenario_params=scene,
            fpga_filters=True,
            extra_event_rate=load,
        )
    )
    cam = open_camera("emulated", backend=be)
    st = DvsState(BiasModel(cam.dvs_family, REF))
    for k, v in controls:
        ch = st.request(k, v)
        st.apply(ch)
        ba, refr = (s * 250 or None for s in (st.ba_filter_steps, st.refractory_filter_steps))
        cam.set_dvs_filters(ba, refr)
    ev = np.concatenate([p.events for p in cam if isinstance(p, EventBatch)] or [np.zeros(0, EVENT_DTYPE)])
    return ev, be


def test_fpga_filters_on_the_emulated_stream():
    # uncorrelated noise only (no light change; the emulator's uniform load, 20 kev/s over 64 x 48 pixels): the
    # background-activity filter lets through only the ~10 % that a neighbour supports within 2 ms
    quiet = {"steps": [], "change_jitter_ms": 0.0}
    off, _ = filtered([("ba_filter_us", 0)], load=20_000.0, **quiet)
    on, be = filtered([("ba_filter_us", 2000)], load=20_000.0, **quiet)
    assert len(off) > 4000 and len(on) < 0.2 * len(off)
    assert be._read(P.DVS.MODULE, P.DVS.STAT_FILTERED_BA + 1) == len(off) - len(on)  # its counter (LSB word)
    # a fast step: the refractory filter (5 ms) leaves at most one event per pixel and 5 ms
    ev, _ = filtered([("ba_filter_us", 0), ("refractory_filter_us", 5000)], **FAST)
    pix = ev["y"].astype(np.int64) * SMALL.width + ev["x"]
    order = np.lexsort((ev["t"], pix))
    same = np.diff(pix[order]) == 0
    assert same.any() and np.diff(ev["t"][order])[same].min() >= 5000
    base, _ = filtered([("ba_filter_us", 0)], **FAST)
    assert len(ev) < 0.5 * len(base)


def test_filters_on_an_emulated_camera_without_them_are_refused():
    be = EmulatedDavis346(EmulatorOptions(scenario="static_lab", duration_s=0.1, sensor=SMALL))
    cam = open_camera("emulated", backend=be)
    before = be.reg(P.DVS.MODULE, P.DVS.FILTER_BACKGROUND_ACTIVITY_TIME)
    with pytest.raises(ParameterError, match="fpga_filters"):
        cam.set_dvs_filters(1000, None)
    assert be.reg(P.DVS.MODULE, P.DVS.FILTER_BACKGROUND_ACTIVITY_TIME) == before
    cam.close()


def test_davis240_biases_on_the_emulated_davis240():
    from necviz.drivers.davis.emulator import CameraVariant

    be = EmulatedDavis346(
        EmulatorOptions(scenario="static_lab", duration_s=0.1, sensor=SMALL, variant=CameraVariant(chip_id=2))
    )
    cam = open_camera("emulated", backend=be)
    assert cam.dvs_family == "DAVIS240"
    st = DvsState(BiasModel(cam.dvs_family, REF))
    ch = st.request("c_on", 0.2)
    assert set(ch.words()) == {1}  # DAVIS240_CONFIG_BIAS_ONBN
    cam.set_dvs_biases(ch.words())
    list(cam)
    assert be._rig.dvs_params.c_on == pytest.approx(0.2, rel=0.01)


def test_scene_cache_and_a_mid_run_change(tmp_path):
    """A stream whose DVS changed mid-run is not cached; one replayed from the cache refuses a mid-run change."""
    from necviz.drivers.sim.rig import SimRig
    from necviz.drivers.sim.scene_cache import SceneCache
    from necviz.drivers.sim.scenes import make_scenario

    cache = SceneCache(tmp_path)

    def rig():
        sc = make_scenario("static_lab", sensor=SMALL, duration_us=150_000, seed=0, **SLOW)
        return SimRig(sc, ["camera"], seed=0, cache=cache)

    r = rig()
    for i, _ in enumerate(r.packets()):
        if i == 10:
            r.set_dvs_params(DvsParams().replace(c_on=0.13))
    assert not r.cache_written  # the stream is not the one its key describes
    r = rig()
    list(r.packets())
    assert r.cache_written
    r = rig()
    gen = r.packets()
    next(gen)
    assert r.samples_cached > 0
    with pytest.raises(ParameterError, match="scene cache"):
        r.set_dvs_params(DvsParams().replace(c_on=0.13))
    gen.close()
    r2 = rig()
    r2.set_dvs_params(DvsParams().replace(c_on=0.13))  # before the run: another stream, simulated
    list(r2.packets())
    assert r2.samples_cached == 0 and r2.dvs_params.c_on == 0.13


def test_a_replay_follows_the_recorded_bias_changes(tmp_path):
    """Record a run whose ON threshold changes mid-run; replaying the .necrec, P-TEDI takes the same change at the
    time it took effect in the recorded stream (scaled from the replay's own thresholds)."""
    from necviz.drivers.recordings import open_recording
    from necviz.pipeline import Lane, Observer, Pipeline, _estimator
    from necviz.runs import make_controller

    rig, pipe = record_a_bias_change(tmp_path / "t.necrec")
    t_live = pipe.dvs.followed_from_us
    assert t_live is not None

    rec = open_recording(tmp_path / "t.necrec")
    lane = Lane("camera", make_controller("nec", sensor=SMALL, limits=rig.camera_info.limits), drives=False)
    replay = Pipeline(rec, [lane], warm_up=False)
    est = _estimator(lane)
    c0 = est.params.c_on
    assert replay.dvs.follow_recording(rec.annotations) == 1
    (scheduled,) = replay.dvs.scheduled  # the public view of what is still to follow: (from_us, ratio on, off)
    assert scheduled[0] == t_live and scheduled[2] == 1.0 and scheduled[1] < 1.0
    seen = []

    class Watch(Observer):
        def events(self, batch):
            seen.append((int(batch["t"][-1]), est.params.c_on))

    replay.observers.append(Watch())
    replay.run().finish()
    assert replay.dvs.followed_from_us == t_live
    assert replay.dvs.scheduled == ()
    old = [last for last, c in seen if c == c0]
    new = [last for last, c in seen if c != c0]
    assert max(old) < t_live <= min(new)
    assert est.params.c_on == pytest.approx(0.13, rel=0.01)  # the recorded model ratio x this lane's own c_on


def test_replay_says_how_many_recorded_bias_changes_it_follows(tmp_path, capsys):
    """``necviz replay`` of a recording with one bias change: the session counts it through
    ``DvsControls.scheduled`` (the public view) and says so."""
    from necviz.commands.cli import main

    record_a_bias_change(tmp_path / "t.necrec")
    assert main(["replay", str(tmp_path / "t.necrec"), "--save", str(tmp_path / "r.rrd")]) == 0
    assert "P-TEDI follows the 1 DVS bias change(s) recorded in the file" in capsys.readouterr().out


@pytest.mark.slow  # a live run of the emulated camera
def test_live_json_states_the_thresholds_ptedi_used(tmp_path):
    """``live --dvs c_on=0.15 --dvs c_off=0.15 --json``: each lane's summary says P-TEDI ran at 0.15 (the
    nearest setting the biases reach), beside its events, and the run's DVS settings are in it."""
    import json

    from necviz.commands.cli import main

    out = tmp_path / "live.json"
    args = ["live", "--device", "emulated", "--scenario", "static_lab", "--duration", "0.5", "--speed", "max"]
    args += ["--dvs", "c_on=0.15", "--dvs", "c_off=0.15", "--json", str(out), "--no-prompt"]
    assert main(args) == 0
    lane = json.loads(out.read_text())["lanes"]["camera"]
    assert lane["events"] > 0
    assert lane["ptedi"]["c_on"] == pytest.approx(0.15, rel=0.01)
    assert lane["ptedi"]["c_off"] == pytest.approx(0.15, rel=0.01)


@pytest.mark.slow  # a live run of the emulated camera
def test_live_with_dvs_writes_the_bias_timeline_into_the_rrd(tmp_path):
    """``live --dvs c_on=0.15 --save``: the .rrd holds the camera's DVS settings and P-TEDI's thresholds as the
    series the live layout's bias timeline shows, styled (named) for it."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from rrd_read import Rrd

    from necviz import schema as S
    from necviz.commands.cli import main

    out = tmp_path / "live.rrd"
    args = ["live", "--device", "emulated", "--scenario", "static_lab", "--duration", "0.3", "--speed", "max"]
    args += ["--dvs", "c_on=0.15", "--save", str(out), "--no-prompt"]
    assert main(args) == 0
    r = Rrd(out)
    _, v = r.series(f"{S.DVS}/c_on")
    assert len(v) and v[-1] == pytest.approx(0.15, rel=0.01)
    _, off = r.series(f"{S.DVS}/c_off")
    assert len(off) and off[-1] != pytest.approx(0.15, rel=0.01)  # only c_on was asked for
    for k in ("refractory_us", "bandwidth_hz"):
        assert len(r.series(f"{S.DVS}/{k}")[1]) and r.series(f"{S.DVS}/{k}")[1][-1] > 0
    _, p = r.series(S.path("camera", S.PTEDI_C_ON))
    assert len(p) and p[-1] == pytest.approx(0.15, rel=0.01)
    assert r.static[f"{S.DVS}/c_on"], "the dvs series carry their names and colours"
