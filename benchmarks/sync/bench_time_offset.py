"""Camera-IMU time offset from VO vs gyro (calib.yaml `timeshift_cam_imu: auto`).

    PYTHONPATH=$PWD .venv/bin/python benchmarks/sync/bench_time_offset.py [--skip-real]

1. Synthetic (`simulate.synthetic_recording`, frames rendered `cam_time_offset_s` after their
   stamps on the IMU clock): a shaky 12 s drive (1 deg shake, 10 fps, 320x180) with a true
   offset of 25 ms, 0 and -40 ms, and the gentle 20 s drive without shake (5 fps, 480x270) with
   25 ms, and a stabilised shaky drive (no offset: must not be taken for one). Per case: sync
   with the calib value 0 (offset ignored), with `auto`, and with the true
   value in calib (oracle): estimate +- 1 sigma, VO-gyro rotation residual at 0 and at the
   estimate, camera rotation error (median, deg) against the ground truth, CPU seconds.
2. The real GoPro Karma clip (`../shared/data/real/gopro_karma.mp4`, imported with
   `blendgen import gopro`): sync with `timeshift_cam_imu: auto` (search +-100 ms), the estimate,
   its uncertainty, the residual before/after, and the VO statuses.
Prints markdown tables (docs/sync.md, "Camera-IMU time offset").
"""

from __future__ import annotations

import argparse
import copy
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: its blendgen, benchmarks.common
from benchmarks.common import REAL  # noqa: E402

from blendgen import so3  # noqa: E402
from blendgen.job.schema import Sync  # noqa: E402
from blendgen.sync.metrics import gt_poses  # noqa: E402
from blendgen.sync.pipeline import run_sync  # noqa: E402
from blendgen.sync.simulate import synthetic_recording  # noqa: E402


def _fmt(x, scale=1.0, nd=1):
    return "-" if x is None else f"{x * scale:+.{nd}f}"


def synthetic() -> None:
    cases = [("shaky 12 s, 10 fps", dict(kind="drive", duration=12.0, fps=10.0, resolution=(320, 180), shake_deg=1.0),
              [0.025, 0.0, -0.04]),
             ("gentle 20 s, 5 fps, no shake", dict(kind="drive", duration=20.0, fps=5.0), [0.025]),
             ("shaky 8 s, stabilised (0.3 s)", dict(kind="drive", duration=8.0, fps=10.0, resolution=(320, 180),
                                                    shake_deg=1.0, stabilise_s=0.3), [0.0])]
    print("| drive | true offset (ms) | calib | estimate +- 1 sigma (ms) | method "
          "| VO-gyro residual at 0 -> used (deg RMS) "
          "| rotation error median (deg) | CPU s |")
    print("|---|---|---|---|---|---|---|---|")
    for name, kw, offsets in cases:
        for off in offsets:
            rec0, _, _ = synthetic_recording(**kw, cam_time_offset_s=off)
            # stabilised frames: the output follows the image (its orientation is the reference)
            ref = rec0.extra.get("image_groundtruth") or gt_poses(rec0.groundtruth)
            for label, calib, est in (("0 (ignored)", 0.0, False), ("auto", 0.0, True), ("true value", off, False)):
                if label == "true value" and off == 0.0:
                    continue
                rec = copy.copy(rec0)
                rec.time_offset_cam_imu, rec.time_offset_estimate = calib, est
                c0 = time.process_time()
                with tempfile.TemporaryDirectory() as d:
                    res = run_sync(rec, Sync(), Path(d), georef=rec.extra["georef"], progress=False)
                cpu = time.process_time() - c0
                err = np.degrees([np.linalg.norm(so3.log(g[:3, :3].T @ p[2][:3, :3])) for g, p in zip(ref, res.poses)])
                s = res.summary["camera_imu_time_offset"]
                est_txt = (f"{_fmt(s['estimate_s'], 1e3)} +- {s['std_s'] * 1e3:.2f}" if est and s["std_s"] is not None
                           else (_fmt(s["estimate_s"], 1e3) + " (flat)" if est else "-"))
                resid = (f"{s['residual_calib_deg']:.3f} -> {s['residual_used_deg']:.3f}"
                         if s.get("residual_calib_deg") is not None else "-")
                print(f"| {name} | {off * 1e3:+.0f} | {label} | {est_txt} | {s['method']} | {resid} | "
                      f"{np.median(err):.3f} | {cpu:.1f} |", flush=True)


def real() -> None:
    import yaml

    from blendgen.recording.folder import read_recording
    from blendgen.recording.importers.gopro import import_gopro

    src = REAL / "gopro_karma.mp4"
    if not src.is_file():
        print(f"{src} missing: real clip skipped")
        return
    with tempfile.TemporaryDirectory() as d:
        rec_dir = Path(d) / "karma"
        import_gopro(src, rec_dir, show_progress=False)
        cal = yaml.safe_load((rec_dir / "calib.yaml").read_text())
        cal["timeshift_cam_imu"] = "auto"
        (rec_dir / "calib.yaml").write_text(yaml.safe_dump(cal, sort_keys=False))
        rec = read_recording(rec_dir)
        c0 = time.process_time()
        res = run_sync(rec, Sync(), Path(d) / "out", progress=False)
        cpu = time.process_time() - c0
    s = res.summary["camera_imu_time_offset"]
    print(f"\nGoPro Karma: {rec.n_frames} frames, IMU {len(rec.imu)} rows, sync {cpu:.1f} CPU s")
    print("camera_imu_time_offset:", {k: v for k, v in s.items() if k != "profile"})
    print("profile (shift s, cost - min):", s["profile"])
    print("vo_status:", res.summary.get("vo_status"))
    print("vo_trust:", {k: v for k, v in res.summary.get("vo_trust", {}).items()})


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--skip-real", action="store_true")
    ap.add_argument("--skip-synthetic", action="store_true")
    a = ap.parse_args()
    if not a.skip_synthetic:
        synthetic()
    if not a.skip_real:
        real()


if __name__ == "__main__":
    main()
