"""Every camera-zoo rig through a whole job, as a user runs it: `blendgen import images` with
the rig's intrinsics, a `ground_plane: auto` job with all seven classes, `blendgen run`.

    nice -n 5 .venv/bin/python benchmarks/analysis/run_zoo_jobs.py [--rigs NAME ...] [--step N]

Prints per rig the exit code, the objects placed per class and the job's warnings, and writes
a contact sheet of the composites: MIT rigs to docs/images/zoo_composites.jpg, CC BY-NC-SA rigs
to benchmarks/results/tmp/zoo/zoo_composites_nc.jpg (never committed). Everything else stays
under benchmarks/results/tmp/zoo/jobs.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from collections import Counter
from pathlib import Path

import cv2
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: its blendgen, benchmarks.common
from benchmarks.common import ROOT  # noqa: E402
from benchmarks.analysis._camera_zoo import TMP, load_rigs  # noqa: E402

from blendgen import CLASSES, atomic  # noqa: E402
from blendgen.report.draw import contact_sheet  # noqa: E402

WORK = TMP / "jobs"


def cli(*args: str, timeout: int = 3600) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "blendgen.cli", *args], capture_output=True, text=True,
                          timeout=timeout, cwd=ROOT)


def run_rig(rig, step: int) -> dict:
    base = WORK / rig.name
    src = base / "src"
    src.mkdir(parents=True, exist_ok=True)
    for f in rig.files:  # only the frames (a folder may hold calibration boards)
        if not (src / f.name).exists():
            (src / f.name).symlink_to(f.resolve())
    calib = base / "calib.yaml"
    calib.write_text(yaml.safe_dump({"camera": rig.camera}))
    r = cli("import", "images", str(src), str(base / "rec"), "--calib", str(calib), "--force", "--no-progress")
    if r.returncode != 0:
        return {"rig": rig.name, "rc": r.returncode, "error": r.stderr[-800:]}
    w = 480
    h = round(w * rig.camera["resolution"][1] / rig.camera["resolution"][0] / 2) * 2
    job = base / "job.yaml"
    job.write_text(yaml.safe_dump({
        "name": f"zoo_{rig.name}", "seed": 7, "recording": "rec", "ground_plane": "auto",
        "frames": {"step": step if rig.n > 20 else 1},
        "inject": {"objects_per_frame": [3, 6], "classes": {c: 1.0 for c in CLASSES}, "distance_m": [5, 40],
                   "sequences": False, "min_projected_px": 12},
        "render": {"resolution": [w, h], "samples": 8, "denoise": True},
        "export": {"formats": ["coco"], "min_visible_px": 8}, "output": "out"}))
    out = base / "out"
    r = cli("run", str(job))
    res = {"rig": rig.name, "rc": r.returncode, "warnings": [ln.strip() for ln in r.stdout.splitlines() if "WARNING" in ln]}
    if r.returncode != 0:
        res["error"] = (r.stdout + r.stderr)[-1500:]
        return res
    plans = [json.loads(x) for x in (out / "plan.jsonl").read_text().splitlines() if x]
    res["frames"] = len(plans)
    res["placed"] = dict(Counter(o["cls"] for p in plans for o in p["objects"]))
    res["max_distance_m"] = sorted({d["value"] for p in plans for d in p.get("decisions", [])
                                    if d.get("what") == "max_distance_m"})
    res["composites"] = sorted(str(p) for p in (out / "frames").glob("*/composite.*"))
    return res


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rigs", nargs="*")
    ap.add_argument("--step", type=int, default=10, help="every STEP-th frame of rigs with more than 20")
    a = ap.parse_args(argv)
    results = []
    tiles = {"mit": [], "nc": []}
    for rig in load_rigs(a.rigs or None):
        res = run_rig(rig, a.step)
        results.append(res)
        print(json.dumps({k: v for k, v in res.items() if k != "composites"}), flush=True)
        for p in res.get("composites", []):
            im = cv2.imread(p)
            if im is not None:
                tiles["mit" if rig.licence == "mit" else "nc"].append((f"{rig.name} {Path(p).parent.name}", im))
    if tiles["mit"]:
        atomic.write_image(ROOT / "docs" / "images" / "zoo_composites.jpg", contact_sheet(tiles["mit"], 3, 400),
                           [cv2.IMWRITE_JPEG_QUALITY, 78])
    if tiles["nc"]:
        atomic.write_image(TMP / "zoo_composites_nc.jpg", contact_sheet(tiles["nc"], 4, 400),
                           [cv2.IMWRITE_JPEG_QUALITY, 85])
    atomic.write_text(TMP / "zoo_jobs.json", json.dumps(results, indent=1))
    return 0 if all(r["rc"] == 0 for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
