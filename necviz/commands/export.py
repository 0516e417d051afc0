"""``necviz export IN OUT``: a recording in any format the readers accept, written as AEDAT 4, HDF5,
NumPy or a native clip — the format chosen by OUT's suffix.

``--start``/``--end`` cut the recording (seconds from its first timestamp, as in ``replay``): what lies
in ``[first + start, first + end)``, frames whose whole exposure lies inside it. The input is
never modified and never overwritten (not even with ``--force``); the output appears only when it is
complete. See docs/recordings.md for what each format holds.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import TYPE_CHECKING

from necviz.commands import Command
from necviz.names import FORMATS
from necviz.progress import LiveLine, output, plural

if TYPE_CHECKING:
    from necviz.options import ExportOptions


def run(options: ExportOptions, out=...) -> dict:
    """Export ``options.file`` to ``options.out_path``; returns :func:`necviz.writers.export_recording`'s statistics.

    Parameters
    ----------
    options : ExportOptions
        What to export where (its range is checked when it is built).
    out : optional
        Where the summary is printed (default: standard output; ``None``: nowhere).

    Returns
    -------
    dict

    Raises
    ------
    ParameterError
        For ``options`` that are not :class:`~necviz.options.ExportOptions`, a bad output name (wrong
        suffix, an existing file without ``force``, the input itself), or a range that holds nothing.
    RecordingError
        For a missing, unreadable or damaged input (no output is left behind).
    """
    from necviz.core.errors import ParameterError
    from necviz.options import ExportOptions
    from necviz.outputs import check_output
    from necviz.writers import SUFFIXES, check_compression, format_for

    if not isinstance(options, ExportOptions):
        raise ParameterError(f"export takes ExportOptions, got {type(options).__name__}")
    out = output(out)
    file, out_path = options.file, options.out_path
    check_compression(format_for(out_path), options.compression)  # before anything is read
    check_output(out_path, "OUT", inputs=[file], force=options.force, suffixes=SUFFIXES)
    from necviz.drivers.recordings import readable_copy

    with readable_copy(file, options.pipe_timeout_s) as source:  # a pipe is read once, into a copy
        return _export(options, out, file, source, out_path)


def _export(options, out, file, source: Path, out_path) -> dict:
    from necviz.commands.replay import open_for_replay
    from necviz.writers import export_recording

    recording, origin = open_for_replay(source, options.exposure_us, options.start_s, options.end_s, options.format)
    line = LiveLine(out if hasattr(out, "isatty") and out.isatty() else None)

    def progress(events, frames, seconds):
        line.show(f"  exporting: {events:,} events, {frames} frames, {seconds:.1f} s")

    try:
        stats = export_recording(
            recording,
            out_path,
            compression=options.compression,
            # the input's name, not the path as typed (a relative path means nothing once the file moves)
            properties={
                "exported_from": Path(file).name,
                "format": recording.format,
                **recording.properties,
            },
            progress=progress,
        )
    finally:
        line.clear()
        recording.close()
    for w in recording.warnings:
        print(f"  warning: {w}", file=out)
    c = stats["counts"]
    span = 0.0 if stats["first_us"] is None else (stats["last_us"] - stats["first_us"]) / 1e6
    print(
        f"  wrote {out_path} ({stats['format']}): {plural(c['events'], 'event')}, {plural(c['frames'], 'frame')}, "
        f"{plural(c['imu'], 'IMU sample')}, {plural(c['triggers'], 'trigger')} over {span:.3f} s",
        file=out,
    )
    stats["origin_us"] = origin
    return stats


def add_arguments(p) -> None:
    from necviz.flags import number

    p.add_argument("file", metavar="IN", help="the recording (any format necviz replay reads)")
    p.add_argument("out", metavar="OUT", help="the output: .aedat4, .h5/.hdf5, .npz or .necrec")
    p.add_argument(
        "--start", type=number("--start"), default=None, metavar="S", help="start S seconds into the recording"
    )
    p.add_argument("--end", type=number("--end"), default=None, metavar="S", help="stop S seconds into the recording")
    p.add_argument("--force", action="store_true", help="replace an existing OUT (never the input)")
    p.add_argument(
        "--exposure-us",
        type=number("--exposure-us"),
        default=None,
        help="exposure for input formats that do not store it",
    )
    p.add_argument("--format", default=None, choices=FORMATS, help="the input's format (skip detection)")
    p.add_argument(
        "--pipe-timeout",
        type=number("--pipe-timeout"),
        default=None,
        metavar="S",
        help="accept a named pipe as IN: copy what it delivers, waiting at most S seconds for it",
    )
    p.add_argument(
        "--compression",
        default=None,
        choices=("lz4", "zstd", "none"),
        help="packet compression of .aedat4 (default lz4) and .necrec (default zstd)",
    )


def _cmd(args) -> int:
    from necviz.options import ExportOptions

    run(
        ExportOptions(
            args.file,
            args.out,
            start_s=args.start,
            end_s=args.end,
            exposure_us=args.exposure_us,
            format=args.format,
            compression=args.compression,
            force=args.force,
            pipe_timeout_s=args.pipe_timeout,
        )
    )
    return 0


COMMAND = Command(
    name="export",
    help="convert a recording to AEDAT 4 (DV), HDF5 (DSEC layout), NumPy .npz or a native clip",
    description=__doc__.split("\n\n")[0].replace("``", "") + " " + __doc__.split("\n\n")[1].replace("``", ""),
    add_arguments=add_arguments,
    run=_cmd,
)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(0)
