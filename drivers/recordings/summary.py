"""``necviz info FILE``: what a recording holds, counted in one bounded-memory pass."""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

import numpy as np

from necviz.core.events import EventBatch
from necviz.core.frames import Frame
from necviz.core.imu import ImuBatch, TriggerBatch


@dataclass
class RecordingInfo:
    """Summary of a recording. Times in µs, duration in s, exposures in µs."""

    path: str
    format: str
    width: int
    height: int
    t_start_us: int | None
    t_end_us: int | None
    duration_s: float
    events: int
    frames: int
    exposure_min_us: int | None
    exposure_max_us: int | None
    exposure_source: str
    imu_samples: int
    triggers: int
    commands: int
    warnings: list[str] = field(default_factory=list)
    sensor_name: str = ""
    on_events: int = 0
    annotations: int = 0
    properties: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """JSON-ready dictionary of every field."""
        return asdict(self)

    def to_text(self) -> str:
        """Aligned ``label: value`` lines for ``necviz info FILE``."""

        def us(v):
            return "-" if v is None else f"{v:,} µs"

        exp = (
            "-"
            if self.exposure_min_us is None
            else f"{self.exposure_min_us:,} µs"
            if self.exposure_min_us == self.exposure_max_us
            else f"{self.exposure_min_us:,} .. {self.exposure_max_us:,} µs"
        )
        on = f" ({100.0 * self.on_events / self.events:.0f} % ON)" if self.events else ""
        rate = f" ({self.events / self.duration_s / 1e6:.3g} Mev/s)" if self.events and self.duration_s > 0 else ""
        name = f" ({self.sensor_name})" if self.sensor_name and self.sensor_name != "custom" else ""
        rows = [
            ("file", self.path),
            ("format", self.format),
            ("sensor", f"{self.width} x {self.height}{name}"),
            ("time", f"{us(self.t_start_us)} .. {us(self.t_end_us)}"),
            ("duration", f"{self.duration_s:.6g} s"),
            ("events", f"{self.events:,}{on}{rate}"),
            ("frames", f"{self.frames:,}"),
            ("exposure", f"{exp} ({self.exposure_source})"),
            ("IMU samples", f"{self.imu_samples:,}"),
            ("triggers", f"{self.triggers:,}"),
            ("commands", f"{self.commands:,}"),
        ]
        if self.annotations:
            rows.append(("annotations", f"{self.annotations:,}"))
        for k, v in self.properties.items():
            rows.append((f"property {k}", str(v)))
        for w in self.warnings:
            rows.append(("warning", w))
        width = max(len(r[0]) for r in rows)
        return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)


def describe(path, progress=None, **open_kwargs) -> RecordingInfo:
    """Open ``path`` with :func:`open_recording` and count what it holds in one streaming pass.

    ``progress(events, frames, seconds)``, if given, is called about twice a second (large files).

    Raises :class:`RecordingError` for unreadable input; damage found mid-file is reported as a
    warning (with what was counted before it) rather than raised, so ``info`` still shows the
    readable part.
    """
    from necviz.drivers.recordings import open_recording
    from necviz.drivers.recordings.reader import RecordingError

    rec = open_recording(path, **open_kwargs)
    events = on = frames = imu = trig = 0
    t0 = t1 = None
    emin = emax = None
    damage = None

    def seen(a, b):
        nonlocal t0, t1
        t0 = a if t0 is None or a < t0 else t0
        t1 = b if t1 is None or b > t1 else t1

    next_report = time.perf_counter() + 0.5
    try:
        for i, pkt in enumerate(rec):
            if progress is not None and not i & 255 and time.perf_counter() >= next_report:
                progress(events, frames, 0.0 if t0 is None else (t1 - t0) / 1e6)
                next_report = time.perf_counter() + 0.5
            match pkt:
                case EventBatch(events=ev) if ev.size:
                    events += ev.size
                    on += int(np.count_nonzero(ev["p"] > 0))
                    seen(int(ev["t"][0]), int(ev["t"][-1]))
                case Frame():
                    frames += 1
                    e = pkt.exposure_us
                    emin = e if emin is None or e < emin else emin
                    emax = e if emax is None or e > emax else emax
                    seen(int(pkt.exposure_start_us), int(pkt.exposure_end_us))
                case ImuBatch():
                    imu += len(pkt)
                    seen(int(pkt.samples["t"][0]), int(pkt.samples["t"][-1]))
                case TriggerBatch():
                    trig += len(pkt)
                    seen(int(pkt.triggers["t"][0]), int(pkt.triggers["t"][-1]))
    except RecordingError as exc:
        damage = f"stopped at damage: {exc}"
    try:
        with rec.converting():
            commands, notes = rec.commands, rec.annotations
    except RecordingError as exc:
        commands, notes = [], []
        damage = damage or f"stopped at damage: {exc}"
    warnings = list(rec.warnings) + ([damage] if damage else [])
    info = RecordingInfo(
        path=str(rec.path),
        format=rec.format,
        width=rec.sensor.width,
        height=rec.sensor.height,
        t_start_us=t0,
        t_end_us=t1,
        duration_s=0.0 if t0 is None else (t1 - t0) / 1e6,
        events=events,
        frames=frames,
        exposure_min_us=emin,
        exposure_max_us=emax,
        exposure_source=rec.exposure_source if frames or rec.exposure_source != "stored" else "none (no frames)",
        imu_samples=imu,
        triggers=trig,
        commands=len(commands),
        warnings=warnings,
        sensor_name=rec.sensor.name,
        on_events=on,
        annotations=len(notes),
        properties=dict(rec.properties),
    )
    rec.close()
    return info
