"""Recording format detection: by content (magic bytes, directory structure), extension only as a fallback.

=============  =====================================================================
format name    recognised by
=============  =====================================================================
``necviz``     ``NECVIZ-REC\\x00`` at byte 0
``aedat4``     ``#!AER-DAT4.0`` at byte 0
``aedat3``     ``#!AER-DAT3.1`` (or 3.0) at byte 0
``aedat2``     ``#!AER-DAT2.0`` at byte 0
``rosbag1``    ``#ROSBAG V2.0`` at byte 0
``rosbag2``    a directory with ``metadata.yaml``; or a ``.db3`` (SQLite) / ``.mcap`` file inside one
``hdf5``       the HDF5 signature ``\\x89HDF\\r\\n\\x1a\\n`` at byte 0, 512, 1024 or 2048
``rpg-text``   a directory holding ``events.txt``; or a text file whose first data line is
               4 numbers (``t x y p``)
=============  =====================================================================
"""

from __future__ import annotations

import re
from pathlib import Path

from necviz.drivers.recordings.reader import RecordingError

FORMATS = ("necviz", "aedat4", "aedat3", "aedat2", "rosbag1", "rosbag2", "hdf5", "rpg-text")
SUPPORTED = (
    "necviz recording (.necrec), AEDAT 4.0, AEDAT 3.1, AEDAT 2.0, ROS1 bag, ROS2 bag, "
    "RPG text (events.txt), HDF5 (DSEC /events, MVSEC davis/left)"
)

_MAGICS = (
    (b"NECVIZ-REC\x00", "necviz"),
    (b"#!AER-DAT4.0", "aedat4"),
    (b"#!AER-DAT3.1", "aedat3"),
    (b"#!AER-DAT3.0", "aedat3"),
    (b"#!AER-DAT2.0", "aedat2"),
    (b"#ROSBAG V2.0", "rosbag1"),
)
HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
_EXTENSIONS = {
    ".necrec": "necviz",
    ".aedat4": "aedat4",
    ".aedat": None,
    ".bag": "rosbag1",
    ".h5": "hdf5",
    ".hdf5": "hdf5",
    ".txt": "rpg-text",
    ".mcap": "rosbag2",
    ".db3": "rosbag2",
}
_EXPECTED = {
    "necviz": "NECVIZ-REC",
    "aedat4": "#!AER-DAT4.0",
    "aedat3": "#!AER-DAT3.1",
    "aedat2": "#!AER-DAT2.0",
    "rosbag1": "#ROSBAG V2.0",
    "hdf5": "the HDF5 signature",
    "rosbag2": "SQLite/MCAP magic",
}
_NUMBER_LINE = re.compile(rb"^\s*[-+]?[0-9.eE+-]+(\s+[-+]?[0-9.eE+-]+){3}\s*$")


def _show(head: bytes) -> str:
    return repr(head[:12])[1:]


def detect_format(path) -> str:
    """The format name of the recording at ``path`` (see the module table), or raise RecordingError."""
    from necviz.drivers.recordings import check_source

    p = Path(path)
    kind = check_source(p)
    if kind == "pipe":
        raise RecordingError(
            f"{p}: a named pipe, not a regular file (its format cannot be detected without reading it)"
        )
    if kind == "folder":
        if (p / "metadata.yaml").is_file():
            return "rosbag2"
        if (p / "events.txt").is_file():
            return "rpg-text"
        raise RecordingError(
            f"{p}: directory is neither a ROS2 bag (metadata.yaml) nor an RPG text "
            f"recording (events.txt); supported: {SUPPORTED}"
        )
    try:
        with open(p, "rb") as f:
            head = f.read(4096)
            blocks = {}
            for off in (512, 1024, 2048):
                f.seek(off)
                blocks[off] = f.read(8)
    except OSError as exc:
        raise RecordingError(f"{p}: cannot read ({exc.strerror})") from None
    if not head:
        raise RecordingError(f"{p}: empty file (0 bytes)")
    for magic, name in _MAGICS:
        if head.startswith(magic):
            return name
    if head.startswith(HDF5_SIGNATURE) or any(b == HDF5_SIGNATURE for b in blocks.values()):
        return "hdf5"
    if head.startswith(b"SQLite format 3\x00") or head.startswith(b"\x89MCAP"):
        if (p.parent / "metadata.yaml").is_file():
            return "rosbag2"
    first = next((ln for ln in head.split(b"\n")[:50] if ln.strip() and not ln.lstrip().startswith(b"#")), b"")
    if _NUMBER_LINE.match(first.rstrip(b"\r")):
        return "rpg-text"
    ext = _EXTENSIONS.get(p.suffix.lower(), "unknown")
    if ext is None or ext in _EXPECTED:
        expected = "an #!AER-DAT header" if ext is None else _EXPECTED[ext]
        raise RecordingError(
            f"{p}: wrong magic for a {p.suffix} file (expected {expected}, found {_show(head)}) at byte 0"
        )
    raise RecordingError(f"{p}: unknown recording format (starts with {_show(head)}); supported: {SUPPORTED}")
