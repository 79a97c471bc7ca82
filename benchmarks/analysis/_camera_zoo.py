"""The camera zoo: real front cameras with known geometry (benchmarks/analysis/camera_zoo_truth.yaml),
imported as blendgen recordings the way a user would (`blendgen import images` with the rig's
intrinsics, or without them: an assumed field of view).

Used by `bench_camera.py --zoo`, `bench_placement.py` and the zoo job runs."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import yaml

from benchmarks.common import REAL
from benchmarks.common import TMP as RESULTS_TMP

TRUTH = Path(__file__).with_name("camera_zoo_truth.yaml")
TMP = RESULTS_TMP / "zoo"
IMAGE_EXTS = (".jpg", ".jpeg", ".png")


def real_dir() -> Path:
    """../shared/data/real beside the project (BLENDGEN_SHARED_DATA points elsewhere)."""
    return REAL


@dataclass
class Rig:
    name: str
    folder: Path
    files: list[Path]
    camera: dict                 # calib.yaml camera section
    licence: str                 # "mit" (overlays may be committed) or "nc" (evaluation only)
    height_m: float | None
    height_exact: bool
    pitch_deg: float | None
    pitch_exact: bool
    roll_deg: float | None
    roll_exact: bool
    mount: str                   # "hood" or "roof"
    hood: list[int]              # per file: 1 hood visible, 0 none (marked by eye)

    @property
    def n(self) -> int:
        return len(self.files)


def _marks(spec, n: int) -> list[int]:
    if isinstance(spec, str) and spec.startswith("all "):
        return [int(spec.split()[1])] * n
    marks = [int(c) for c in str(spec) if c in "01"]
    if len(marks) != n:
        raise ValueError(f"hood marks: {len(marks)} for {n} frames")
    return marks


def load_rigs(only: list[str] | None = None) -> list[Rig]:
    """The rigs whose frames are present (a missing folder is skipped with its name printed)."""
    doc = yaml.safe_load(TRUTH.read_text())
    out = []
    for name, r in doc["rigs"].items():
        if only and name not in only:
            continue
        folder = real_dir() / r["folder"]
        files = ([folder / f for f in r["files"]] if "files" in r else
                 sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_EXTS) if folder.is_dir() else [])
        files = [f for f in files if f.is_file()]
        if not files:
            print(f"  {name}: no frames in {folder} (skipped)")
            continue
        out.append(Rig(name, folder, files, r["camera"], r["licence"], r.get("height_m"), r.get("height_exact", False),
                       r.get("pitch_deg"), r.get("pitch_exact", False), r.get("roll_deg"), r.get("roll_exact", False),
                       r["mount"], _marks(r["hood"], len(files))))
    return out


def import_rig(rig: Rig, *, calibrated: bool = True, root: Path | None = None) -> Path:
    """`blendgen import images` of the rig's frames (cached under benchmarks/results/tmp/zoo):
    with its intrinsics from calib.yaml, or `calibrated=False`: the importer's assumed
    field of view (the focal length is then estimated from the frames)."""
    from blendgen.recording.importers.images import import_images

    root = root or TMP / "recs"
    dst = root / (rig.name + ("" if calibrated else "_nocalib"))
    src = root / "src" / rig.name
    if (dst / "frames.csv").is_file():
        return dst
    src.mkdir(parents=True, exist_ok=True)
    for f in rig.files:  # the folder may hold other images (calibration boards); link the frames only
        link = src / f.name
        if not link.exists():
            link.symlink_to(f.resolve())
    calib = None
    if calibrated:
        calib = root / f"{rig.name}_calib.yaml"
        calib.write_text(yaml.safe_dump({"camera": rig.camera}))
    import_images(src, dst, calib=calib, force=True, show_progress=False)
    return dst


# ----------------------------------------------------------------------------- the zoo benchmark

GRID = {"size_scale": (1.0, 1.05, 1.1, 1.15, 1.2), "vp_sys_deg": (0.3, 0.5, 1.0, 2.0), "frame_dev_deg": (0.25, 0.5, 1.0)}
CROSS_GRID = (5, 4, 6, 3)   # ties go to the first (the deployed value)


def per_frame(rig: Rig, rec, detector, cross_px: int | None = None) -> dict:
    """The analysis' per-frame part on every frame of the rig, as the stage runs it: hood
    candidates (and their consensus), the detector's road users, the camera cues; with CPU s."""
    import time

    from blendgen.analysis import hood as hood_mod
    from blendgen.analysis import objects
    from blendgen.analysis.camera import frame_cues
    from blendgen.analysis.stage import not_ego
    from blendgen.frame_analysis import hood_mask
    from blendgen.recording.frames import read_frames

    ids = [rec.frame_id(i) for i in range(rec.n_frames)]
    old = hood_mod.CROSS_PX
    if cross_px is not None:
        hood_mod.CROSS_PX = cross_px
    try:
        t0 = time.process_time()
        hoods = hood_mod.find_hood(rec, ids)
        t_hood = time.process_time() - t0
    finally:
        hood_mod.CROSS_PX = old
    cues, cpu = {}, {}
    for fid, im in read_frames(rec, ids):
        t0 = time.process_time()
        users = not_ego(objects.road_users(im, detector), hood_mask(hoods[fid], im.shape[1], im.shape[0]),
                        im.shape[1], im.shape[0])[0]
        cues[fid] = frame_cues(im, rec.camera, hood=hoods[fid], users=[(o.cls, o.box) for o in users])
        cpu[fid] = time.process_time() - t0 + t_hood / len(ids)
    return {"ids": ids, "hoods": hoods, "cues": cues, "cpu": cpu}


def hood_only(rig: Rig, rec, cross_px: int) -> dict:
    from blendgen.analysis import hood as hood_mod

    old = hood_mod.CROSS_PX
    hood_mod.CROSS_PX = cross_px
    try:
        return hood_mod.find_hood(rec, [rec.frame_id(i) for i in range(rec.n_frames)])
    finally:
        hood_mod.CROSS_PX = old


def camera_metrics(rig: Rig, m) -> dict:
    """Errors of a mount against the rig's reference: height (relative), pitch and roll per
    frame against the calibration, or against the rig's own median where it is approximate."""
    import numpy as np

    p = np.array(list(m.frame_pitch.values()))
    r = np.array(list(m.frame_roll.values()))
    out = {"height_m": m.height_m, "height_std": m.height_std_log, "pitch_med": float(np.median(p)),
           "roll_med": float(np.median(r)), "cues": dict(m.cues)}
    out["height_err"] = (m.height_m / rig.height_m - 1) if rig.height_m else None
    for name, v, ref, exact in (("pitch", p, rig.pitch_deg, rig.pitch_exact), ("roll", r, rig.roll_deg, rig.roll_exact)):
        base = ref if (exact and ref is not None) else float(np.median(v))
        e = np.abs(v - base)
        out[f"{name}_ref"] = "calibration" if (exact and ref is not None) else "rig median"
        out[f"{name}_p90"] = float(np.percentile(e, 90))
        out[f"{name}_med_err"] = float(np.median(e))
        out[f"{name}_spread"] = float(np.percentile(np.abs(v - np.median(v)), 90))
    return out


def objective(met: dict) -> float:
    """What a constant is tuned to (lower is better): each Done-when limit as one unit, summed
    as absolute values (squares let the one-frame rig with a 20 % height error decide)."""
    j = met["pitch_p90"] / 1.0 + met["roll_p90"] / 1.0
    if met["height_err"] is not None:
        j += abs(met["height_err"]) / 0.05
    return j


def leave_one_rig_out(scores: dict[str, dict], keys: list) -> dict[str, object]:
    """For each rig: the key minimising the summed score of the other rigs."""
    out = {}
    for held in scores:
        others = [r for r in scores if r != held]
        out[held] = min(keys, key=lambda k: sum(scores[r][k] for r in others)) if others else keys[0]
    return out
