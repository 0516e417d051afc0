"""``necviz repair FILE.rrd``: make a recording cut short by a crash whole again.

A run ended by SIGKILL, a power cut or a full disk leaves its ``.rrd`` without the footer Rerun
writes on a clean close: the viewer still streams it, but tools that index the file
(``RrdReader(...).store()``, ``rerun rrd verify``) refuse it. Everything logged up to the crash is
in the file; repairing rewrites it through ``rerun rrd merge`` (the ``rerun`` program that ships
with the SDK), which writes a new file with its footer. The input is never modified: the repaired
copy goes to ``--out`` (default ``FILE.repaired.rrd``), refused if it exists unless ``--force``.
A long session's ``--save`` file is written in segments (``FILE.rrd``, then ``FILE.rrd.parts/``) that
are joined when the run ends; after a crash, repairing joins them too.
(Native ``.necrec`` recordings need no repair: they are readable up to their last flush.)
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from necviz.commands import Command
from necviz.core.errors import ParameterError
from necviz.outputs import atomic_write, check_output


def rerun_program() -> list[str]:
    from necviz.dashboard.viewer import _rerun_program

    return _rerun_program()


def repair(path, out=None, force: bool = False) -> Path:
    """Write a repaired copy of the recording ``path``; returns its path."""
    src = Path(path)
    if not src.is_file():
        raise ParameterError(f"{src}: no such recording")
    with open(src, "rb") as f:
        if f.read(4) != b"RRF2":
            raise ParameterError(f"{src}: not a Rerun recording (.rrd)")
    dst = Path(out) if out is not None else src.with_name(src.stem + ".repaired.rrd")
    check_output(dst, "--out", inputs=[src], force=force, suffixes=(".rrd",))
    from necviz.dashboard.rrd_file import segment_files

    files = [str(p) for p in segment_files(src)]  # a segmented --save file cut short: its parts too
    with atomic_write(dst, "wb") as f:
        proc = subprocess.run([*rerun_program(), "rrd", "merge", *files], stdout=f, stderr=subprocess.PIPE)
        if proc.returncode != 0:
            lines = [ln for ln in proc.stderr.decode(errors="replace").splitlines() if ln.strip()]
            raise ParameterError(f"{src}: cannot be repaired ({lines[-1] if lines else 'rerun rrd merge failed'})")
    return dst


def add_arguments(p) -> None:
    p.add_argument("file", metavar="FILE.rrd", help="the recording cut short")
    p.add_argument("--out", metavar="OUT.rrd", help="where the repaired copy goes (default FILE.repaired.rrd)")
    p.add_argument("--force", action="store_true", help="replace an existing --out file")


def _cmd(args) -> int:
    dst = repair(args.file, args.out, args.force)
    print(f"wrote {dst} (open it with: rerun {dst})")
    return 0


COMMAND = Command(
    name="repair",
    help="make an .rrd cut short by a crash whole again (a repaired copy)",
    description=__doc__.split("\n\n")[1],
    add_arguments=add_arguments,
    run=_cmd,
)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(0)
