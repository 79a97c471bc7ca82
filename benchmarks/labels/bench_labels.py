"""Labels benchmark: time to extract per-frame labels, write them, export COCO/YOLO/KITTI
as the number of frames grows, and the realism detector's time per frame.

    .venv/bin/python benchmarks/labels/bench_labels.py [--quick]

Prints a table, writes benchmarks/results/labels.png and docs/benchmarks/labels.md.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: its blendgen, benchmarks.common
from benchmarks.common import DETECTOR, DOCS, REAL, RESULTS  # noqa: E402

from blendgen import CLASSES, atomic  # noqa: E402
from blendgen.frame_labels import write_frame_labels  # noqa: E402
from blendgen.geometry import Camera, R_world_cam_from_ypr, invert_pose, make_pose  # noqa: E402
from blendgen.labels.export import export_labels  # noqa: E402
from blendgen.labels.instances import extract_instances  # noqa: E402
from blendgen.plan import FramePlan, PlacedObject  # noqa: E402

DIMS = {"person": (0.5, 0.6, 1.75), "bicycle": (1.8, 0.6, 1.1), "car": (4.5, 1.8, 1.5),
        "motorcycle": (2.1, 0.8, 1.3), "bus": (12.0, 2.5, 3.2), "truck": (8.0, 2.5, 3.5),
        "traffic light": (0.3, 0.3, 0.9)}


def make_frame(rng, camera, n_objects, frame_id):
    """A plan with random objects ahead and its id image (projected boxes, painted far to near)."""
    T = make_pose(R_world_cam_from_ypr(0.0), [0.0, 0.0, 1.5])
    names = list(CLASSES)
    objs = []
    for k in range(n_objects):
        cls = names[int(rng.integers(len(names)))]
        z = 4.0 if cls == "traffic light" else 0.0
        objs.append(PlacedObject(k + 1, cls, (float(rng.uniform(6, 60)), float(rng.uniform(-12, 12)), z),
                                 float(rng.uniform(-np.pi, np.pi)), DIMS[cls]))
    index = np.zeros((camera.height, camera.width), np.int32)
    Tcw = invert_pose(T)
    amodal = {}
    for o in sorted(objs, key=lambda o: -o.position[0]):
        uv, _ = camera.project(o.box_corners_world() @ Tcw[:3, :3].T + Tcw[:3, 3])
        m = np.zeros_like(index, np.uint8)
        cv2.fillConvexPoly(m, cv2.convexHull(np.round(uv).astype(np.int32)), 1)
        amodal[o.id] = int(m.sum())
        index[m.astype(bool)] = o.id
    return index, FramePlan(frame_id, 0.0, T.tolist(), objs), amodal


def run(quick: bool):
    camera = Camera.from_hfov(1280, 720, 90.0)
    rng = np.random.default_rng(0)
    frame_counts = [10, 40] if quick else [10, 50, 200]
    rows, export_t = [], {f: [] for f in ("coco", "yolo", "kitti")}
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out"
        paths, t_extract, t_write = [], [], []
        comp = np.full((720, 1280, 3), 90, np.uint8)
        for k in range(max(frame_counts)):
            fid = f"f{k:06d}"
            index, plan, amodal = make_frame(rng, camera, 8, fid)
            t0 = time.perf_counter()
            inst = extract_instances(index, plan, camera, amodal_px=amodal, min_visible_px=64,
                                     small_objects="ignore")
            t_extract.append(time.perf_counter() - t0)
            d = out / "frames" / fid
            d.mkdir(parents=True)
            cv2.imwrite(str(d / "composite.png"), comp)
            t0 = time.perf_counter()
            write_frame_labels(d / "labels.json", fid, f"frames/{fid}/composite.png", 1280, 720, inst,
                               camera=camera)
            t_write.append(time.perf_counter() - t0)
            paths.append(d / "labels.json")
        rows.append(("extract_instances, 1280x720, 8 objects", "per frame", np.median(t_extract) * 1e3))
        rows.append(("write_frame_labels", "per frame", np.median(t_write) * 1e3))
        for n in frame_counts:
            for fmt in export_t:
                ts = []
                for _ in range(1 if n > 100 else 3):
                    t0 = time.perf_counter()
                    export_labels(out, paths[:n], [fmt])
                    ts.append(time.perf_counter() - t0)
                export_t[fmt].append(np.median(ts))
                rows.append((f"export {fmt}", f"{n} frames", np.median(ts) * 1e3))
    if DETECTOR.exists():
        from blendgen.detection.detector import YoloxDetector

        det = YoloxDetector(DETECTOR)
        imgs = sorted((REAL / "udacity_highway_images").glob("*.jpg"))
        img = cv2.imread(str(imgs[0])) if imgs else comp
        det(img)  # warm-up
        ts = []
        for _ in range(5 if quick else 20):
            t0 = time.perf_counter()
            det(img)
            ts.append(time.perf_counter() - t0)
        rows.append((f"YOLOX-Nano detect {img.shape[1]}x{img.shape[0]} (onnxruntime CPU)", "per frame",
                     np.median(ts) * 1e3))
    return rows, frame_counts, export_t


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--outputs", type=Path, default=None,
                    help="write the plot and the table here instead of benchmarks/results and docs/benchmarks")
    args = ap.parse_args()
    rows, counts, export_t = run(args.quick)
    table = ["| step | size | median ms |", "|---|---|---:|"]
    table += [f"| {a} | {b} | {c:.1f} |" for a, b, c in rows]
    print("\n".join(table))

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.5))
    for fmt, ts in export_t.items():
        ax.plot(counts, np.asarray(ts) * 1e3 / np.asarray(counts), "o-", label=fmt)
    ax.set_xlabel("frames exported"), ax.set_ylabel("ms per frame (median)"), ax.set_xscale("log")
    ax.set_title("label export time per frame"), ax.legend()
    fig.tight_layout()
    res = args.outputs or RESULTS
    res.mkdir(parents=True, exist_ok=True)
    with atomic.atomic_path(res / "labels.png") as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    cmd = "nice -n 5 .venv/bin/python benchmarks/labels/bench_labels.py" + (" --quick" if args.quick else "")
    doc = (args.outputs or DOCS) / "labels.md"
    doc.parent.mkdir(parents=True, exist_ok=True)
    atomic.write_text(doc, "# Labels benchmark\n\nProduced by `" + cmd + "` on the shared 2-core development machine "
                   "(timings noisy; medians).\n\n" + "\n".join(table) + "\n\n![export time](../../benchmarks/results/labels.png)\n")
    print(f"\nwrote {res / 'labels.png'} and {doc}")


if __name__ == "__main__":
    main()
