"""`blendgen calibrate RECORDING [--out FILE]`: the camera over the road, from the frames.

Runs the hood search, the camera estimate (pitch, roll, height, focal length per frame,
blendgen.analysis.camera) and, for a video, the ego motion over the ground plane; prints a
summary and writes RECORDING/ground_plane.yaml (atomically): a `summary` and one entry per
frame (t, height_m, pitch_deg, roll_deg, yaw_deg, fx, confidence, source, reasons,
horizon, hood, lane direction, and for a video the position over the ground). The lane
markings' yaw (analysis.lane_direction) over the frames is the camera's yaw in the car that
sync takes from calib.yaml `vehicle.camera_yaw_deg` when it has no video to see it.
"""

from __future__ import annotations

import argparse
import time
from collections import Counter
from pathlib import Path

import numpy as np


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "calibrate", help="estimate camera height, pitch, roll (and the hood) from a recording's frames",
        description="Estimate the camera over the road from the frames of RECORDING (vanishing points of "
                    "lane markings, road edges and buildings; lane-width prior or real cars for the height) "
                    "and write RECORDING/ground_plane.yaml. Fix any value with --height/--pitch/--roll.")
    p.add_argument("recording", type=Path, help="recording folder (calib.yaml, frames.csv)")
    p.add_argument("--out", type=Path, default=None, help="output YAML (default RECORDING/ground_plane.yaml)")
    p.add_argument("--step", type=int, default=1, help="use every STEP-th frame (long videos)")
    p.add_argument("--height", type=float, default=None, help="fix the camera height (m)")
    p.add_argument("--pitch", type=float, default=None, help="fix the pitch (deg, > 0 up)")
    p.add_argument("--roll", type=float, default=None, help="fix the roll (deg)")
    p.add_argument("--lane-width", type=float, default=None,
                   help="the road's lane width (m) when known: the height then scales with it (default: a prior)")
    p.add_argument("--detector", type=Path, default=None,
                   help="ONNX YOLOX model: real cars' widths also give the height")
    p.add_argument("--per-image", action="store_true",
                   help="stills from different cameras (photos of different cars): a mount per image")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_run)


def _user(args):
    from pydantic import ValidationError

    from blendgen.errors import UserError
    from blendgen.job.schema import GroundPlane

    kw = {"camera_height_m": args.height, "pitch_deg": args.pitch, "roll_deg": args.roll}
    try:
        lane = {} if args.lane_width is None else {"lane_width_m": args.lane_width}
        return GroundPlane(**{k: ("auto" if v is None else v) for k, v in kw.items()}, **lane,
                           stills="per_image" if args.per_image else "shared")
    except ValidationError as e:
        err = e.errors()[0]
        flag = {"camera_height_m": "--height", "pitch_deg": "--pitch", "roll_deg": "--roll",
                "lane_width_m": "--lane-width"}.get(str(err["loc"][0]), str(err["loc"][0]))
        raise UserError(f"{flag}: {err['msg'].removeprefix('Value error, ')} (got {err.get('input')!r})") from None


def _car_boxes(rec, frame_ids, model: Path, progress: bool) -> dict[str, list]:
    from blendgen.detection.detector import YoloxDetector
    from blendgen.recording.frames import read_frames

    det = YoloxDetector(model, score_min=0.4, category_ids={3})      # COCO 3: car
    return {fid: [d["bbox"] for d in det(im)] for fid, im in read_frames(rec, frame_ids, progress=progress,
                                                                          desc="cars") if im is not None}


def calibrate(rec, frame_ids, user, *, car_boxes=None, progress: bool = False) -> dict:
    """The document written to ground_plane.yaml."""
    from blendgen.analysis.camera import estimate_cameras
    from blendgen.analysis.egomotion import ground_track
    from blendgen.analysis.hood import find_hood
    from blendgen.analysis.lane_direction import LANE_HEADING_STD_DEG, lane_direction
    from blendgen.recording.frames import frame_indices, is_sequence, read_frames

    t0 = time.process_time()
    hoods = find_hood(rec, frame_ids, progress=progress, shared=getattr(user, "stills", "shared") == "shared")
    cams = estimate_cameras(rec, frame_ids, user=user, car_boxes=car_boxes, hoods=hoods, progress=progress)
    track = ground_track(rec, frame_ids, cams, hoods=hoods, progress=progress) if is_sequence(rec) else None
    lanes = {fid: lane_direction(im, rec.camera, hood=hoods.get(fid)) for fid, im in
             read_frames(rec, frame_ids, progress=progress, desc="lane markings") if im is not None}
    cpu = time.process_time() - t0
    frames = []
    times = dict(zip(frame_ids, rec.frames_t[frame_indices(rec, frame_ids)]))
    for fid in frame_ids:
        est, horizon = cams[fid]
        row = {"id": fid, "t": float(times[fid]), "height_m": round(est.height_m, 3),
               "pitch_deg": round(est.pitch_deg, 3), "roll_deg": round(est.roll_deg, 3),
               "yaw_deg": None if est.yaw_deg is None else round(est.yaw_deg, 3),
               "fx": None if est.fx is None else round(est.fx, 1), "confidence": round(est.confidence, 3),
               "source": dict(est.source), "reasons": list(est.reasons),
               "horizon": None if horizon is None else [[round(a, 1) for a in p] for p in horizon],
               "hood": None if hoods.get(fid) is None else [[round(a, 1) for a in p] for p in hoods[fid]],
               "lane_direction": lanes[fid].summary() if fid in lanes else {"reason": "unreadable frame"}}
        if track is not None:
            T = track.poses[fid]
            row["position_m"] = [round(float(T[0, 3]), 3), round(float(T[1, 3]), 3)]
            row["ego_motion"] = track.steps[fid].status
        frames.append(row)
    est = [cams[f][0] for f in frame_ids]

    def med(key):
        return round(float(np.median([getattr(e, key) for e in est])), 3)

    summary = {"frames": len(frame_ids), "sequence": bool(is_sequence(rec)),
               "height_m": med("height_m"), "pitch_deg": med("pitch_deg"), "roll_deg": med("roll_deg"),
               "fx": est[0].fx if est and est[0].fx else rec.camera.fx,
               "confidence_median": med("confidence"),
               "sources": {q: dict(Counter(e.source.get(q, "-") for e in est)) for q in ("height", "pitch", "roll")},
               "fallback_frames": sum(1 for e in est if e.reasons),
               "hood_frames": sum(1 for f in frame_ids if hoods.get(f) is not None),
               "cpu_s_per_frame": round(cpu / max(len(frame_ids), 1), 4)}
    yaws = np.array([r.yaw_deg for r in lanes.values() if r.yaw_deg is not None])
    if len(yaws):
        # the car's heading in its lane wanders between frames: their spread is the error
        # (fewer than 5 frames: the first one's fit and the lane keeping)
        one = next(r for r in lanes.values() if r.yaw_deg is not None)
        std = (1.4826 * float(np.median(np.abs(yaws - np.median(yaws)))) / np.sqrt(len(yaws)) if len(yaws) >= 5
               else float(np.hypot(one.yaw_std_deg, LANE_HEADING_STD_DEG)) / np.sqrt(len(yaws)))
        summary["lane_yaw_deg"] = round(float(np.median(yaws)), 3)
        summary["lane_yaw_std_deg"] = round(float(max(std, 0.1)), 3)
    summary["lane_yaw_frames"] = int(len(yaws))
    if track is not None:
        last = track.poses[frame_ids[-1]]
        summary["travelled_m"] = round(float(np.hypot(last[0, 3], last[1, 3])), 2)
    return {"recording": str(rec.root), "summary": summary, "frames": frames}


def _run(args: argparse.Namespace) -> int:
    import yaml

    from blendgen import atomic
    from blendgen.errors import UserError
    from blendgen.recording.folder import read_recording

    if args.step < 1:
        raise UserError(f"--step: expected >= 1, got {args.step}")
    user = _user(args)
    rec = read_recording(args.recording, require_frames=True)
    ids = [rec.frame_id(i) for i in range(0, rec.n_frames, args.step)]
    cars = _car_boxes(rec, ids, args.detector, not args.quiet) if args.detector else None
    doc = calibrate(rec, ids, user, car_boxes=cars, progress=not args.quiet)
    out = args.out or (args.recording / "ground_plane.yaml")
    atomic.write_text(out, yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=120))
    s = doc["summary"]
    print(f"{s['frames']} frames ({'video' if s['sequence'] else 'stills'}): camera height {s['height_m']} m, "
          f"pitch {s['pitch_deg']:+.2f} deg, roll {s['roll_deg']:+.2f} deg, fx {s['fx']:.1f} px "
          f"(median confidence {s['confidence_median']:.2f})")
    for q, c in s["sources"].items():
        print(f"  {q:7s} from " + ", ".join(f"{k} x{v}" for k, v in c.items()))
    print(f"  hood in {s['hood_frames']} frames; {s['fallback_frames']} frames fell back (reasons in the file)"
          + (f"; ego car travelled {s['travelled_m']} m" if "travelled_m" in s else ""))
    if "lane_yaw_deg" in s:
        print(f"  lane markings in {s['lane_yaw_frames']} frames: camera yaw in the car {s['lane_yaw_deg']:+.2f} "
              f"+- {s['lane_yaw_std_deg']:.2f} deg (calib.yaml vehicle.camera_yaw_deg for sync without video)")
    else:
        print("  no frame with lane markings on both sides: no camera yaw in the car")
    print(f"  {s['cpu_s_per_frame'] * 1000:.0f} ms CPU per frame; wrote {out}")
    return 0
