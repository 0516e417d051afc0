"""Parameter sweeps: grids of closed-loop simulator runs on Dask ``distributed``, results in Parquet.

``necviz sweep plan|run|status|report|show`` (:mod:`.cli`). A TOML sweep file (:mod:`.spec`)
expands into runs — scenario × scenario parameters × simulator overrides × camera profile ×
controller × controller parameters × seed — each a plain-dict spec for
:func:`necviz.runs.run_spec` keyed by a hash of the full spec. :mod:`.engine` runs them on an
embedded local cluster of worker processes (or an existing Dask cluster) with
:func:`.worker.execute`, writing each finished run atomically into ``OUT/runs/`` (:mod:`.store`);
:mod:`.report` turns the rows into per-cell means with 95 % confidence intervals (Markdown, CSV,
plots); :mod:`.show` re-runs one run in the Rerun dashboard. From Python::

    from necviz.sweeps import SweepOptions, load_plan, run_sweep, report
    plan = load_plan("benchmarks/sweeps/example.toml")
    run_sweep(plan, "out/example", SweepOptions(workers=2))
    report("out/example")
"""

from necviz.core.lazy import lazy_exports

_WHERE = {
    "SweepOptions": "engine",
    "SweepResult": "engine",
    "connect": "engine",
    "run_sweep": "engine",
    "status": "engine",
    "report": "report",
    "Plan": "spec",
    "Run": "spec",
    "SweepFileError": "spec",
    "load_plan": "spec",
    "spec_hash": "spec",
}


# imported on use: `necviz --help` loads necviz.commands.sweep without Dask or NumPy
__getattr__, __dir__ = lazy_exports(__name__, {name: f".{module}" for name, module in _WHERE.items()})


__all__ = [
    "Plan",
    "Run",
    "SweepFileError",
    "SweepOptions",
    "SweepResult",
    "connect",
    "load_plan",
    "report",
    "run_sweep",
    "spec_hash",
    "status",
]
