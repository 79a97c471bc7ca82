"""The camera zoo: real front cameras with known geometry (benchmarks/camera_zoo_truth.yaml),
imported as blendgen recordings the way a user would (`blendgen import images` with the rig's
intrinsics, or without them: an assumed field of view).

Used by `bench_camera.py --zoo`, `bench_placement.py` and the zoo job runs."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
TRUTH = Path(__file__).with_name("camera_zoo_truth.yaml")
TMP = ROOT / "benchmarks" / "results" / "tmp" / "zoo"
IMAGE_EXTS = (".jpg", ".jpeg", ".png")


def real_dir() -> Path:
    """../shared/data/real beside the project (BLENDGEN_SHARED_DATA points elsewhere)."""
    return Path(os.environ.get("BLENDGEN_SHARED_DATA", ROOT.parent / "shared" / "data")) / "real"


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
