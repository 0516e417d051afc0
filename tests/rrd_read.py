"""Reading an .rrd back in tests: which entities hold what, and scalar series as arrays."""

from __future__ import annotations

from collections import defaultdict

import numpy as np
import pyarrow as pa
from rerun.chunk import RrdReader


def _flat(col) -> list:
    out = []
    for v in col.to_pylist():
        if isinstance(v, list):
            out.extend(v)
        else:
            out.append(v)
    return out


class Rrd:
    """Everything in a recording, indexed by entity path (without the leading '/')."""

    def __init__(self, path):
        self.components: dict[str, set] = defaultdict(set)
        self.rows: dict[str, int] = defaultdict(int)
        self._batches: dict[str, list] = defaultdict(list)
        self.timelines: dict[str, set] = defaultdict(set)
        self.kinds: dict[str, set] = defaultdict(set)  # entity -> archetypes logged on it (e.g. "Scalars")
        self.properties: dict[str, dict] = defaultdict(dict)  # recording properties: name -> {key: value}
        self.static: dict[str, dict] = defaultdict(dict)  # entity -> {component: values} logged static (styles)
        for ch in RrdReader(str(path)).stream().to_chunks():
            ent = str(ch.entity_path).lstrip("/")
            rb = ch.to_record_batch()
            if ent.startswith("__properties/"):
                for n in rb.schema.names:
                    if not n.startswith("rerun."):
                        v = _flat(rb.column(n))
                        self.properties[ent.split("/", 1)[1]][n] = v[-1] if v else None
            names = [n for n in rb.schema.names if ":" in n]
            self.components[ent].update(names)
            self.kinds[ent].update(n.split(":", 1)[0] for n in names)
            self.timelines[ent].update(ch.timeline_names or ())
            if ch.timeline_names:  # static style rows have no timeline
                self.rows[ent] += ch.num_rows
                self._batches[ent].append(rb)
            else:
                for n in names:
                    self.static[ent][n] = _flat(rb.column(n))

    def property(self, name: str, key: str):
        """A recording property (``rr.send_property(name, rr.AnyValues(key=...))``)."""
        return self.properties.get(name, {}).get(key)

    def has_timeline(self, entity: str, timeline: str) -> bool:
        return timeline in self.timelines.get(entity, ())

    def schema(self) -> dict[str, frozenset]:
        """Entity path -> the archetypes it holds (what two recordings must share to show alike)."""
        return {e: frozenset(k) for e, k in self.kinds.items() if not e.startswith("__")}

    def has(self, entity: str, component: str) -> bool:
        return any(c == component or c.endswith(component) for c in self.components.get(entity, ()))

    def series(self, entity: str, timeline: str = "t") -> tuple[np.ndarray, np.ndarray]:
        """``(times, values)`` of a Scalars entity, sorted by time (duration timelines in seconds)."""
        ts, vs = [], []
        for rb in self._batches.get(entity, []):
            if "Scalars:scalars" not in rb.schema.names or timeline not in rb.schema.names:
                continue
            col = rb.column(timeline)
            if pa.types.is_duration(col.type):  # nanoseconds, read exactly (timedelta has µs only)
                t = (col.cast(pa.int64()).to_numpy(zero_copy_only=False) / 1e9).tolist()
            else:
                t = [float(x) for x in col.to_pylist()]
            v = _flat(rb.column("Scalars:scalars"))
            ts.extend(t)
            vs.extend(v)
        order = np.argsort(ts, kind="stable")
        return np.asarray(ts, float)[order], np.asarray(vs, float)[order]

    def times(self, entity: str, *timelines: str) -> np.ndarray:
        """Rows x timelines: each row's value on every given timeline (durations in seconds), in time order."""
        rows = []
        for rb in self._batches.get(entity, []):
            if not all(tl in rb.schema.names for tl in timelines):
                continue
            cols = []
            for tl in timelines:
                col = rb.column(tl)
                cols.append(
                    col.cast(pa.int64()).to_numpy(zero_copy_only=False) / (1e9 if pa.types.is_duration(col.type) else 1)
                )
            rows.extend(zip(*cols, strict=True))
        return np.asarray(sorted(rows), float).reshape(-1, len(timelines))

    def static_values(self, entity: str, component: str) -> list:
        """The values of a component logged static on ``entity`` (e.g. ``SeriesLines:colors``), ``[]`` if none."""
        return list(self.static.get(entity, {}).get(component, []))

    def column(self, entity: str, component: str) -> list:
        """Every row's value of a temporal component of ``entity``, in chunk order (``None`` where a row lacks it)."""
        out = []
        for rb in self._batches.get(entity, []):
            if component in rb.schema.names:
                out.extend(rb.column(component).to_pylist())
            else:
                out.extend([None] * rb.num_rows)
        return out

    def texts(self, entity: str) -> list[str]:
        out = []
        for rb in self._batches.get(entity, []):
            if "TextLog:text" in rb.schema.names:
                out.extend(_flat(rb.column("TextLog:text")))
        return out
