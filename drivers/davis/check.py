"""What a DAVIS camera actually sends: a few seconds of its raw bulk stream, decoded and summarised.

:func:`capture` configures the camera as ``necviz live`` does (libcaer's defaults, the given exposure and
frame interval), streams for ``seconds`` and keeps every transfer with its arrival time (optionally written
to a capture file, :mod:`.capture`); :func:`analyse` decodes a capture and says what it held: events,
frames (complete, dropped, without exposure specials), IMU samples, triggers, the exposure each frame echoed
against the register, the first frame's word sequence and the transfer timing, with a one-line verdict.
``necviz devices --check`` prints it (:func:`report_lines`). It exists for the first hour with a real
camera: every assumption the driver makes about the stream is visible in its output.
"""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from necviz.core.frames import Frame
from necviz.core.imu import TRIGGER_KINDS, TriggerBatch
from necviz.drivers.davis.camera import ECHO_TOLERANCE_CYCLES, ECHO_TOLERANCE_REL
from necviz.drivers.davis.capture import HEADER_DEVICE_FIELDS, Capture, CaptureWriter
from necviz.drivers.davis.color import COLOR_FILTERS
from necviz.drivers.davis.device import BulkReader, DavisDevice
from necviz.drivers.davis.device_errors import DeviceDisconnectedError, DeviceError

#: seconds of stream ``necviz devices --check`` records by default
CHECK_SECONDS = 2.0
#: the exposure and frame interval the check configures (µs): ``necviz live``'s defaults
CHECK_EXPOSURE_US = 5000.0
CHECK_FRAME_INTERVAL_US = 20_000.0
#: seconds to wait for the first transfer before giving up (the verdict then says the camera sent nothing)
NO_DATA_S = 10.0

_SPECIAL_NAMES = {1: "TSRESET", 8: "FS-GS", 9: "FS-RS", 10: "FE", 11: "R", 12: "S", 13: "CE", 14: "ES", 15: "EE"}
_IMU_NAMES = {0: "none", 1: "MPU6050/6150", 2: "MPU9250"}


@dataclass
class CheckReport:
    """What :func:`analyse` found in a capture (see the module docstring); ``level`` is OK, WARN or FAIL."""

    device: dict
    registers: dict
    seconds: float
    bytes: int
    transfers: int
    truncated: bool
    decoded: dict
    echoes: Counter
    echo_offsets: Counter
    first_frame: str
    gaps_ms: tuple[float, float, float] | None
    size_median: float | None
    level: str = "OK"
    verdict: str = ""
    notes: list[str] = field(default_factory=list)


def capture(
    device: DavisDevice,
    seconds: float = CHECK_SECONDS,
    path=None,
    *,
    exposure_us: float = CHECK_EXPOSURE_US,
    frame_interval_us: float = CHECK_FRAME_INTERVAL_US,
) -> Capture:
    """Configure ``device``, stream ``seconds`` of wall-clock time from the first transfer (waiting at most
    :data:`NO_DATA_S` for it) and return every transfer (written to ``path`` as they arrive, if given; the file
    must not exist). The device is stopped, not closed.

    Raises
    ------
    DeviceError
        The camera was unplugged or a USB read failed (what arrived before is in the file).
    """
    device.send_default_config(exposure_us, frame_interval_us)
    registers = {
        "exposure_us": float(exposure_us),
        "exposure_cycles": device.us_to_cycles(exposure_us),
        "frame_interval_us": float(frame_interval_us),
        "frame_interval_cycles": device.us_to_cycles(frame_interval_us),
    }
    info = device.info
    header = {k: info.get(k) for k in HEADER_DEVICE_FIELDS}
    writer = CaptureWriter(path, info, registers) if path is not None else None
    cap = Capture(header, registers)
    reader = BulkReader(device)
    device.start()
    reader.start()
    t_start = time.monotonic_ns()
    t0 = None  # the first transfer's arrival: the recording lasts ``seconds`` from it
    try:
        while True:
            now = time.monotonic_ns()
            if (t0 is not None and now - t0 >= seconds * 1e9) or (t0 is None and now - t_start >= NO_DATA_S * 1e9):
                break
            item = reader.get(0.05)
            if item is None:
                continue
            kind, payload = item
            if kind == "data":
                if t0 is None:
                    t0 = time.monotonic_ns()
                t = time.monotonic_ns() - t0
                cap.transfers.append((t, payload))
                if writer is not None:
                    writer.add(t, payload)
            elif kind == "finished":  # an emulated scene that ended
                break
            elif kind == "disconnected":
                raise DeviceDisconnectedError(f"{device.kind} {device.serial} was unplugged during the check")
            else:
                raise DeviceError(f"{device.kind} {device.serial}: USB read failed during the check: {payload}")
    finally:
        reader.stop()
        try:
            device.stop()
        except DeviceError:
            pass
        if writer is not None:
            writer.close()
    return cap


def _token(w: int) -> str | None:
    """A word's name in the frame sequence (None: not an APS word: time, DVS, IMU)."""
    if w & 0x8000:
        return None
    code, data = w >> 12, w & 0xFFF
    if code == 0:
        return _SPECIAL_NAMES.get(data)
    if code == 4:
        return "adc"
    if code == 5:
        return "roi" if (data >> 8) & 0xF in (1, 2) else None
    if code == 6:
        return "exp" if (data >> 10) & 3 == 0 else None
    return None


def word_sequence(words: np.ndarray, header_words: int = 11) -> str:
    """The APS words of the stream's first frame, compressed: from up to ``header_words`` ROI/exposure words
    before its start to its end, runs counted (``adc×260``) and repeated columns grouped
    (``(R adc×260 CE)×346``). Time, DVS and IMU words are left out."""
    codes = words.astype(np.int64)
    starts = np.flatnonzero((codes == 8) | (codes == 9))
    if starts.size == 0:
        return "no frame start (special 8/9) in the stream"
    s = int(starts[0])
    ends = np.flatnonzero(codes[s:] == 10)
    e = s + int(ends[0]) if ends.size else codes.size - 1
    tokens: list[str] = []
    before = []
    i = s - 1
    while i >= 0 and len(before) < header_words:  # the header words just before the start, if any
        tok = _token(int(codes[i]))
        if tok in ("roi", "exp"):
            before.append(tok)
        elif tok is not None:
            break
        i -= 1
    tokens += before[::-1]
    tokens += [t for t in (_token(int(w)) for w in codes[s : e + 1]) if t is not None]
    runs: list[tuple[str, int]] = []
    for t in tokens:
        if runs and runs[-1][0] == t:
            runs[-1] = (t, runs[-1][1] + 1)
        else:
            runs.append((t, 1))
    out: list[str] = []
    k = 0
    while k < len(runs):
        col = runs[k : k + 3]
        if len(col) == 3 and col[0][0] in ("R", "S") and col[0][1] == 1 and col[1][0] == "adc" and col[2] == ("CE", 1):
            n = 1
            while runs[k + 3 * n : k + 3 * n + 3] == col:
                n += 1
            out.append(f"({col[0][0]} adc×{col[1][1]} CE)×{n}")
            k += 3 * n
            continue
        t, c = runs[k]
        out.append(t if c == 1 else f"{t}×{c}")
        k += 1
    if not ends.size:
        out.append("… (no frame end)")
    return " ".join(out)


def analyse(cap: Capture) -> CheckReport:
    """Decode a capture and judge it (see the module docstring)."""
    dec = cap.decoder()
    echoes: Counter = Counter()
    offsets: Counter = Counter()
    triggers: Counter = Counter()
    reg = int(cap.registers.get("exposure_cycles", -1) or -1)
    tol = max(ECHO_TOLERANCE_CYCLES, ECHO_TOLERANCE_REL * reg)
    # no finish(): a frame cut by the end of the capture is not a dropped frame
    for p in (p for _, data in cap.transfers for p in dec.decode(data)):
        if isinstance(p, Frame):  # read as it comes: the decoder keeps the last 64 frames' echoes
            cyc = dec.frame_cycles.get(p.sequence, -1)
            if cyc < 0:
                echoes["absent"] += 1
            else:
                d = cyc - reg
                offsets[d] += 1
                echoes["equal" if d == 0 else "near" if abs(d) <= tol else "other"] += 1
        elif isinstance(p, TriggerBatch):
            triggers.update(TRIGGER_KINDS[int(k)] for k in p.triggers["kind"])
    decoded = dict(dec.stats)
    decoded["trigger_kinds"] = dict(triggers)
    times = np.array([t for t, _ in cap.transfers], np.int64)
    sizes = np.array([len(b) for _, b in cap.transfers], np.int64)
    gaps = np.diff(times) / 1e6 if times.size > 1 else np.zeros(0)
    report = CheckReport(
        device=cap.device,
        registers=cap.registers,
        seconds=float(times[-1] - times[0]) / 1e9 if times.size > 1 else 0.0,
        bytes=int(sizes.sum()),
        transfers=int(times.size),
        truncated=cap.truncated,
        decoded=decoded,
        echoes=echoes,
        echo_offsets=offsets,
        first_frame=word_sequence(cap.words()),
        gaps_ms=(float(np.median(gaps)), float(np.percentile(gaps, 99)), float(gaps.max())) if gaps.size else None,
        size_median=float(np.median(sizes)) if sizes.size else None,
    )
    _judge(report)
    return report


def _judge(r: CheckReport) -> None:
    """Set ``level`` and ``verdict``: FAIL when nothing usable was decoded, WARN for what the driver copes with
    but a user should know, OK otherwise."""
    d = r.decoded
    frames, events = d["frames"], d["events"]
    warn = []
    if r.truncated:
        warn.append("the capture file is cut short")
    if d["frames_dropped"]:
        warn.append(f"{_n(d['frames_dropped'], 'frame')} dropped (wrong column counts)")
    if d["frames_without_exposure"]:
        warn.append("the logic sends no exposure specials: exposures are placed from the readout")
    if r.echoes["absent"]:
        warn.append(f"{_n(r.echoes['absent'], 'frame')} reported no exposure value: commands are matched by time")
    if r.echoes["other"]:
        warn.append(
            f"{_n(r.echoes['other'], 'frame')} echoed an exposure far from the register: commands will not match"
        )
    if d["skipped_words"]:
        warn.append(f"{d['skipped_words']:,} words skipped as invalid")
    warn += list(r.device.get("notes") or [])
    if r.bytes == 0:
        r.level, r.verdict = "FAIL", "the camera sent nothing (is it streaming? try replugging it)"
    elif frames == 0 and (events or d["frames_dropped"] or d["frames_without_exposure"]):
        r.level = "FAIL"
        r.verdict = f"{events:,} events but no complete frame (see the first frame's words above)" + (
            "; " + "; ".join(warn) if warn else ""
        )
    elif frames == 0:
        r.level, r.verdict = "FAIL", f"nothing decoded from {r.bytes // 2:,} words (see the first frame's words)"
    elif warn:
        r.level, r.verdict = "WARN", f"{_n(frames, 'frame')} and {events:,} events decoded, but " + "; ".join(warn)
    else:
        how = "exactly" if r.echoes["near"] == 0 else f"within {ECHO_TOLERANCE_CYCLES} cycles"
        r.verdict = (
            f"{_n(frames, 'frame')} and {events:,} events decoded; every frame echoed the exposure register {how}"
        )


def _n(k: int, what: str) -> str:
    return f"{k:,} {what}{'' if k == 1 else 's'}"


def _clock_line(dev: dict) -> str:
    c, regs = dev.get("clocks_mhz") or {}, dev.get("clock_registers") or {}
    dev_f = (regs.get("deviation") or 1000) / 1000
    return (
        f"  clocks: ADC {c.get('adc', 0):.3f} MHz ({regs.get('adc', '?')} MHz x {dev_f:g}), "
        f"logic {c.get('logic', 0):.3f} MHz, USB {c.get('usb', 0):.3f} MHz"
    )


def report_lines(r: CheckReport, capture_path=None) -> list[str]:
    """The report as printed by ``necviz devices --check``, ending with the verdict line."""
    dev, d = r.device, r.decoded
    where = "emulated" if dev.get("emulated") else "USB"
    (w, h), (aw, ah) = dev.get("dvs_size") or (0, 0), dev.get("aps_size") or (0, 0)
    cf = COLOR_FILTERS.get(dev.get("color_filter", 0), f"filter {dev.get('color_filter')}")
    shutter = "global shutter" if dev.get("global_shutter") else "rolling shutter"
    lines = [
        f"{dev.get('kind')} {dev.get('serial')} ({where})",
        f"  firmware {dev.get('firmware')}, logic {dev.get('logic')} (patch {dev.get('logic_patch')}), "
        f"chip {dev.get('chip')} (id {dev.get('chip_id')}), {'master' if dev.get('master') else 'slave'}",
        _clock_line(dev),
        f"  DVS {w}x{h} (orientation {dev.get('dvs_orientation', 0)}), APS {aw}x{ah} (orientation "
        f"{dev.get('aps_orientation', 0)}, {cf}, {shutter}), IMU {_IMU_NAMES.get(dev.get('imu_type'), '?')}",
    ]
    saved = f" -> {capture_path}" if capture_path is not None else ""
    lines.append(
        f"  captured {r.bytes / 1e6:.2f} MB in {r.transfers:,} transfers over {r.seconds:.2f} s (first to last){saved}"
    )
    rate = d["events"] / r.seconds / 1e6 if r.seconds > 0 else 0.0
    lines.append(f"  events    {d['events']:,} ({rate:.2f} Mev/s)")
    lines.append(
        f"  frames    {d['frames']} complete, {d['frames_dropped']} dropped (column counts), "
        f"{d['frames_without_exposure']} without exposure specials"
    )
    trig = ", ".join(f"{n} {k}" for k, n in sorted(d["trigger_kinds"].items())) or "none"
    lines.append(f"  IMU       {d['imu_samples']:,} samples ({d['imu_dropped']} dropped); triggers: {trig}")
    reg, us = r.registers.get("exposure_cycles"), r.registers.get("exposure_us")
    e = r.echoes
    register = f"register {reg:,} cycles ({us:g} µs)" if reg is not None and us is not None else "register unknown"
    lines.append(
        f"  exposure  {register}; frames echoed it: {e['equal']} exactly, "
        f"{e['near']} within {ECHO_TOLERANCE_CYCLES} cycles, {e['other']} off, {e['absent']} no value"
    )
    if r.echo_offsets and set(r.echo_offsets) != {0}:
        common = ", ".join(f"{k:+d} ({n})" for k, n in r.echo_offsets.most_common(4))
        lines.append(f"            echo - register: {common}")
    lines.append(f"  first frame: {r.first_frame}")
    if r.gaps_ms is not None:
        med, p99, mx = r.gaps_ms
        lines.append(
            f"  transfers: one every {med:.2f} ms (median), p99 {p99:.2f} ms, longest gap {mx:.2f} ms; "
            f"{r.size_median / 1e3:.1f} kB median"
        )
    lines.append(f"verdict: {r.level} — {r.verdict}")
    return lines


__all__ = [
    "CHECK_EXPOSURE_US",
    "CHECK_FRAME_INTERVAL_US",
    "CHECK_SECONDS",
    "CheckReport",
    "analyse",
    "capture",
    "report_lines",
    "word_sequence",
]
