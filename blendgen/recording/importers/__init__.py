"""Importers: other recording layouts -> the one recording folder of DESIGN.md.

`import_recording(fmt, src, dst, **options)` dispatches to one importer per format; each
writes through `blendgen.recording.folder` and the result reads with `read_recording`.
`check_recording(dst)` says what is missing or odd. Importer modules load lazily so that a
format's optional dependency (rosbags) is needed only for that format.
"""

from __future__ import annotations

import importlib
from pathlib import Path

from blendgen.recording.importers.check import Finding, check_recording, format_findings  # noqa: F401

FORMATS = {
    "video": ("blendgen.recording.importers.video", "import_video"),
    "images": ("blendgen.recording.importers.images", "import_images"),
    "euroc": ("blendgen.recording.importers.euroc", "import_euroc"),
    "kitti": ("blendgen.recording.importers.kitti", "import_kitti"),
    "comma2k19": ("blendgen.recording.importers.comma2k19", "import_comma2k19"),
    "gopro": ("blendgen.recording.importers.gopro", "import_gopro"),
    "rosbag": ("blendgen.recording.importers.rosbag", "import_rosbag"),
}


def import_recording(fmt: str, src, dst, **options) -> Path:
    from blendgen.errors import UserError

    if fmt not in FORMATS:
        raise UserError(f"unknown format {fmt!r}; expected one of {list(FORMATS)}")
    module, func = FORMATS[fmt]
    return getattr(importlib.import_module(module), func)(src, dst, **options)
