"""Rerun output of a comparison: one recording, one entity subtree per controller.

Entity paths (the dashboard issue documents the full schema): ``NAME/frame`` (APS image, JPEG),
``NAME/exposure/commanded`` and ``NAME/exposure/applied`` (µs), ``NAME/gain/commanded`` and
``NAME/gain/applied``, ``NAME/over_exposed_rate``, ``NAME/under_exposed_rate``,
``NAME/saturated`` (a text-log marker on each frame more than 50 % saturated), and for NEC
``NAME/irradiance/predicted`` (P-TEDI ln P at each command). Timelines: ``t`` (sensor time, s)
and ``frame`` (each camera's frame number). Run settings are recording properties.
Scalars are buffered and sent as columns at the end (one call per series).
"""

from __future__ import annotations

import uuid
from collections import defaultdict
from pathlib import Path

import numpy as np
import rerun as rr


class CompareRecording:
    def __init__(self, path: str | Path, properties: dict):
        self.path = Path(path)
        self.rec = rr.RecordingStream("necviz", recording_id=str(uuid.uuid4()))
        self.rec.save(str(self.path))
        self.rec.send_recording_name(f"necviz compare: {properties.get('scenario', '')}")
        self.rec.send_property("run", rr.AnyValues(**{k: str(v) for k, v in properties.items()}))
        self._series: dict[str, list] = defaultdict(list)

    def frame(self, name: str, t_us: int, seq: int, image: np.ndarray, over: float, under: float) -> None:
        self.rec.set_time("t", duration=t_us / 1e6)
        self.rec.set_time("frame", sequence=seq)
        self.rec.log(f"{name}/frame", rr.Image(image, color_model="L").compress(jpeg_quality=85))
        if max(over, under) > 0.5:
            kind = "over" if over >= under else "under"
            self.rec.log(f"{name}/saturated", rr.TextLog(f"frame {seq}: {max(over, under):.0%} {kind}-exposed",
                                                          level=rr.TextLogLevel.WARN))

    def scalar(self, path: str, t_us: int, value: float) -> None:
        self._series[path].append((t_us, value))

    def close(self) -> None:
        for path, pts in self._series.items():
            arr = np.asarray(pts, dtype=np.float64)
            self.rec.send_columns(path, indexes=[rr.TimeColumn("t", duration=arr[:, 0] / 1e6)],
                                  columns=rr.Scalars.columns(scalars=arr[:, 1]))
        self.rec.flush()
        rr.disconnect(self.rec)
