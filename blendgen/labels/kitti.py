"""KITTI object layout: label_2/<frame>.txt, calib/<frame>.txt, image_2/<frame>.png (links).

label_2 line: `type truncated occluded alpha left top right bottom h w l x y z rotation_y`.
The 2D box uses COCO's pixel-edge convention (right = x + w). The 3D box is exact (from the
plan): (x, y, z) is the bottom-face centre in camera coordinates. Objects marked ignore are
written as `DontCare` (KITTI's ignore regions).

Types (`export.kitti_types`): "kitti" (default) uses only the devkit's types, which KITTI
tools keep (they drop any other): person Pedestrian, car Car, truck Truck, bicycle Cyclist
(blendgen's bicycles carry a rider, like KITTI's Cyclist box), bus and motorcycle Misc, traffic
light DontCare (not an object class in KITTI: an ignore region). "extended" keeps a type per
blendgen class (Bicycle, Motorcycle, Bus, TrafficLight), which KITTI's own tools drop.
Riders are separate person instances (COCO's convention): KITTI's Cyclist in both modes
(Motorcyclist for a motorcycle's rider in "extended"); the two-wheeler itself stays its own
line (Misc in "kitti": KITTI has no bicycle or motorcycle type).

Real road users of the background (source user or detector) have a 2-D box only: their
lines carry KITTI's "unknown" 3-D fields (dimensions -1, location -1000, rotation_y and alpha
-10). label_2 cannot say where a label came from: source_2/<frame>.txt holds, line for line,
injected, user or detector.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from blendgen import atomic
from blendgen.frame_labels import all_instances
from blendgen.labels.yolo import link_image

KITTI_TYPES = {  # export.kitti_types -> blendgen class -> KITTI type
    "kitti": {"person": "Pedestrian", "bicycle": "Misc", "car": "Car", "motorcycle": "Misc",
              "bus": "Misc", "truck": "Truck", "traffic light": "DontCare"},
    "extended": {"person": "Pedestrian", "bicycle": "Bicycle", "car": "Car", "motorcycle": "Motorcycle",
                 "bus": "Bus", "truck": "Truck", "traffic light": "TrafficLight"},
}
DEVKIT_TYPES = ("Car", "Van", "Truck", "Pedestrian", "Person_sitting", "Cyclist", "Tram", "Misc", "DontCare")


def kitti_type(inst: dict, types: str = "kitti") -> str:
    """KITTI type; a rider is KITTI's Cyclist (their own box: the two-wheeler stays a separate
    instance)."""
    rides = inst.get("rides")
    if inst["cls"] == "person" and rides:
        return "Cyclist" if types == "kitti" or rides["cls"] == "bicycle" else "Motorcyclist"
    if inst["cls"] not in KITTI_TYPES[types]:  # an ignore region of no known class
        return "DontCare"
    return KITTI_TYPES[types][inst["cls"]]


def occluded_state(occlusion: float | None) -> int:
    """KITTI occluded: 0 fully visible, 1 partly, 2 largely occluded, 3 unknown."""
    if occlusion is None:
        return 3
    return 0 if occlusion <= 0.1 else (1 if occlusion <= 0.5 else 2)


def label_line(inst: dict, types: str = "kitti") -> str:
    x, y, w, h = (float(v) for v in inst["bbox"])
    box = f"{x:.2f} {y:.2f} {x + w:.2f} {y + h:.2f}"
    kind = kitti_type(inst, types)
    if inst["ignore"] or kind == "DontCare":
        return f"DontCare -1 -1 -10 {box} -1 -1 -1 -1000 -1000 -1000 -10"
    b = inst.get("box3d_cam")
    if b is None:  # a real object: its 2-D box only
        return (f"{kind} {float(inst.get('truncation') or 0.0):.2f} {occluded_state(inst.get('occlusion'))} "
                f"-10 {box} -1 -1 -1 -1000 -1000 -1000 -10")
    hh, ww, ll = b["dimensions_hwl"]
    lx, ly, lz = b["location"]
    return (f"{kind} {float(inst.get('truncation') or 0.0):.2f} "
            f"{occluded_state(inst.get('occlusion'))} {b['alpha']:.2f} {box} "
            f"{hh:.2f} {ww:.2f} {ll:.2f} {lx:.2f} {ly:.2f} {lz:.2f} {b['rotation_y']:.2f}")


def calib_text(camera: dict) -> str:
    """KITTI calib file: every projection matrix is the rendered camera (no stereo, no lidar)."""
    P = np.array([[camera["fx"], 0, camera["cx"], 0], [0, camera["fy"], camera["cy"], 0], [0, 0, 1, 0]])
    p = " ".join(f"{v:.12e}" for v in P.ravel())
    eye = " ".join(f"{v:.12e}" for v in np.eye(3).ravel())
    tr = " ".join(f"{v:.12e}" for v in np.eye(4)[:3].ravel())
    return (f"P0: {p}\nP1: {p}\nP2: {p}\nP3: {p}\nR0_rect: {eye}\n"
            f"Tr_velo_to_cam: {tr}\nTr_imu_to_velo: {tr}\n")


def parse_label_line(line: str) -> dict:
    f = line.split()
    return {"type": f[0], "truncated": float(f[1]), "occluded": int(f[2]), "alpha": float(f[3]),
            "bbox": [float(v) for v in f[4:8]], "dimensions_hwl": [float(v) for v in f[8:11]],
            "location": [float(v) for v in f[11:14]], "rotation_y": float(f[14])}


def write_kitti(root: Path, frames: list[dict], types: str = "kitti") -> dict:
    n_calib = 0
    for fr in frames:
        fid = fr["frame_id"]
        insts = all_instances(fr)
        atomic.write_text(root / "label_2" / f"{fid}.txt", "".join(label_line(i, types) + "\n" for i in insts))
        atomic.write_text(root / "source_2" / f"{fid}.txt",
                          "".join(i.get("source", "injected") + "\n" for i in insts))
        link_image(root / "image_2" / (fid + Path(fr["image_path"]).suffix), fr["image_path"])
        if fr.get("camera"):
            atomic.write_text(root / "calib" / f"{fid}.txt", calib_text(fr["camera"]))
            n_calib += 1
    return {"dir": str(root), "label_files": len(frames), "calib_files": n_calib, "types": types,
            "type_of_class": KITTI_TYPES[types]}
