"""A folder of still photos -> a recording with frames only (e.g. dashcam stills).

Frames are one second apart on the recording clock (stills have no shared timeline);
use them with a `ground_plane` job, which needs no sync. Every image must have the same
size; the camera is a pinhole from --calib or an assumed horizontal field of view.
`labels` (COCO JSON, YOLO or KITTI label folder) become the recording's labels.json
(blendgen.recording.labels), matched to the images by file name.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from blendgen.errors import UserError
from blendgen.recording import folder
from blendgen.recording.importers import common
from blendgen.recording.importers.video import DEFAULT_HFOV_DEG, _load_user_calib
from blendgen.recording.labels import IMAGE_EXTS, parse_class_map, read_labels, write_recording_labels


def import_images(src, dst, *, calib=None, hfov_deg: float | None = None, force: bool = False,
                  show_progress: bool = True, labels=None, label_format: str | None = None,
                  class_map=None) -> Path:
    src = Path(src)
    if not src.is_dir():
        raise UserError("image folder not found", where=str(src))
    files = sorted(p for p in src.iterdir() if p.suffix.lower() in IMAGE_EXTS)
    if not files:
        raise UserError(f"no images ({', '.join(IMAGE_EXTS)}) in the folder", where=str(src))
    size = None
    for p in common.progress(files, desc="check images", enabled=show_progress):
        img = cv2.imread(str(p), cv2.IMREAD_COLOR)
        if img is None:
            raise UserError("does not decode as an image", where=str(p))
        if size is None:
            size = img.shape[:2]
        elif img.shape[:2] != size:
            raise UserError(f"is {img.shape[1]}x{img.shape[0]} but {files[0].name} is {size[1]}x{size[0]}; "
                            "all images of a recording share one camera", where=str(p))
    h, w = size
    frame_labels = None
    if labels is not None:  # read and checked before anything is written
        if label_format is None:
            raise UserError("--labels needs --label-format coco, yolo or kitti", where=str(labels))
        cmap = parse_class_map(class_map)
        boxes = read_labels(labels, label_format, {p.name: (w, h) for p in files}, class_map=cmap)
        frame_labels = {f"f{i:06d}": boxes[p.name] for i, p in enumerate(files) if p.name in boxes}
    elif label_format is not None or class_map:
        raise UserError("--label-format and --class-map go with --labels PATH")
    dst = common.prepare_output(dst, force)
    if calib is not None:
        camera, _, _ = _load_user_calib(Path(calib), w, h)
        cam_note = f"from {calib}"
    else:
        hf = float(hfov_deg) if hfov_deg else DEFAULT_HFOV_DEG
        camera = common.default_camera(w, h, hf)
        cam_note = f"assumed pinhole with {hf:g} deg horizontal field of view"
    names = []
    for i, p in enumerate(files):
        name = f"frames/{i:06d}{p.suffix.lower()}"
        common.place_file(p, dst / name)
        names.append(name)
    folder.write_frames_csv(dst, np.arange(len(files), dtype=float), names)
    meta = common.import_meta("images", src, camera=cam_note, T_cam_imu="not applicable (no IMU)",
                              notes=["stills: frames are 1 s apart on the recording clock",
                                     *(f"{n} <- {p.name}" for n, p in zip(names, files))])
    folder.write_calib(dst, camera, None, None, extra={"import": meta})
    if frame_labels is not None:
        write_recording_labels(dst, frame_labels, w, h, {"path": str(Path(labels).resolve()), "format": label_format,
                                                         "class_map": cmap})
    return dst
