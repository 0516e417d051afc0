"""Reading an .rrd back in tests: which entities hold what, and scalar series as arrays."""

from __future__ import annotations

from collections import defaultdict

import numpy as np
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
        for ch in RrdReader(str(path)).stream().to_chunks():
            ent = str(ch.entity_path).lstrip("/")
            rb = ch.to_record_batch()
            names = [n for n in rb.schema.names if ":" in n]
            self.components[ent].update(names)
            if ch.timeline_names:  # static style rows have no timeline
                self.rows[ent] += ch.num_rows
                self._batches[ent].append(rb)

    def has(self, entity: str, component: str) -> bool:
        return any(c == component or c.endswith(component) for c in self.components.get(entity, ()))

    def series(self, entity: str, timeline: str = "t") -> tuple[np.ndarray, np.ndarray]:
        """``(times, values)`` of a Scalars entity, sorted by time (duration timelines in seconds)."""
        ts, vs = [], []
        for rb in self._batches.get(entity, []):
            if "Scalars:scalars" not in rb.schema.names or timeline not in rb.schema.names:
                continue
            t = rb.column(timeline).to_pylist()
            v = _flat(rb.column("Scalars:scalars"))
            for ti, vi in zip(t, v):
                ts.append(ti.total_seconds() if hasattr(ti, "total_seconds") else float(ti))
                vs.append(vi)
        order = np.argsort(ts, kind="stable")
        return np.asarray(ts, float)[order], np.asarray(vs, float)[order]

    def texts(self, entity: str) -> list[str]:
        out = []
        for rb in self._batches.get(entity, []):
            if "TextLog:text" in rb.schema.names:
                out.extend(_flat(rb.column("TextLog:text")))
        return out
