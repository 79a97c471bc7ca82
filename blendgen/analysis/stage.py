"""The analysis stage: once per background frame of a ground-plane job, before planning.

For each frame: camera estimate and horizon, hood, real road users (detector ->
footprints), road region and bands, road direction, and the camera pose over the road.
Leaves `OUT/analysis/<frame_id>.json` (frame_analysis.FrameAnalysis) and `<frame_id>_road.png`
(255 road, 128 band); a frame whose JSON exists is not analysed again, so an interrupted
stage resumes where it stopped. Nothing here raises on a hard frame: every quantity that
cannot be estimated falls back with its reason in `decisions`.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np

from blendgen import atomic, ground, lane_geometry
from blendgen.analysis import lanes, objects, road
from blendgen.analysis.mount import placement_limit
from blendgen.frame_analysis import BAND, ROAD, CameraEstimate, FrameAnalysis, hood_mask, read_analysis, write_analysis
from blendgen.geometry import Camera

log = logging.getLogger(__name__)
EGO_BOX_MIN_WIDTH = 0.5   # a "vehicle" box this wide (fraction of the image) touching the bottom is our own hood
LANE_WIDTH_MISFIT = 0.15  # the ego lane measured this far off the job's lane width: the camera does not fit


def not_ego(users: list, hmask: np.ndarray | None, W: int, H: int) -> tuple[list, list]:
    """(road users, boxes of our own hood): a very wide box touching the frame's bottom, or
    one centred on the hood, is the ego vehicle."""
    kept, dropped = [], []
    for o in users:
        x, y, w, h = o.box
        on_hood = hmask is not None and hmask[int(min(y + h / 2, H - 1)), int(min(x + w / 2, W - 1))]
        (dropped if (w > EGO_BOX_MIN_WIDTH * W and y + h >= H - 0.05 * H) or on_hood else kept).append(o)
    return kept, dropped


def analyse_frame(image: np.ndarray, frame_id: str, camera: Camera, est: CameraEstimate, detector, *,
                  horizon=None, hood=None, user_road: np.ndarray | None = None, user_walk: np.ndarray | None = None,
                  T_world_cam: np.ndarray | None = None, users: list | None = None,
                  oncoming: str = "auto", lane_width_m: float = 3.5,
                  ) -> tuple[FrameAnalysis, np.ndarray | None]:
    """One frame's analysis and its road/walkable-band mask (uint8, or None without a road).
    `users`: the frame's detections when already run (`objects.road_users`); `user_road`,
    `user_walk`: the user's masks (bool HxW) that replace the estimates. `oncoming`: the job's
    `ground_plane.oncoming` (where traffic comes towards the camera)."""
    H, W = image.shape[:2]
    decisions: list[dict] = []

    def decide(what, value, reason):
        decisions.append({"what": what, "value": value, "reason": reason})
        if value is None:  # a fallback: say it where the user looks (the run's log)
            log.warning("%s: %s: %s", frame_id, what, reason)

    T0 = ground.camera_pose(est)
    if horizon is None:
        horizon = ground.horizon(camera, T0)
    hmask = hood_mask(hood, W, H)
    hood_top = float(np.asarray(hood)[:, 1].min()) if hood else None
    decide("camera", {"height_m": est.height_m, "pitch_deg": est.pitch_deg, "roll_deg": est.roll_deg},
           "; ".join(est.reasons) or ", ".join(f"{k}: {v}" for k, v in est.source.items()))
    decide("hood", hood is not None, "hood polygon found" if hood else "no hood found: the whole frame is scene")
    limit, why = placement_limit(est.pitch_std_deg, est.roll_std_deg, est.height_std_rel, camera.hfov_deg)
    decisions.append({"what": "placement_max_m", "value": None if limit is None else round(limit, 1), "reason": why})

    kept, dropped = not_ego(objects.road_users(image, detector) if users is None else users, hmask, W, H)
    for o in dropped:
        decide("real_object_dropped", {"cls": o.cls, "box": o.box}, "the ego vehicle's own hood, not a road user")
    decide("real_objects", len(kept), f"{detector.model_path.name}, score >= {detector.score_min}")

    mask = None
    if user_road is not None:
        road_px, how = user_road, "user mask masks/road"
    else:
        road_px, how = road.estimate_road(image, horizon, hmask, [o.box for o in kept])
    decide("road", None if road_px is None else round(float(road_px.mean()), 4), how)

    if est.yaw_deg is not None:  # the camera estimate's road vanishing point
        yaw, how = -est.yaw_deg, "the camera estimate's vanishing point of the road"
    else:
        yaw, how = road.road_direction(image, road_px, camera, T0, horizon)
    decide("road_direction_deg", None if yaw is None else round(yaw, 2),
           how if yaw is not None else f"straight ahead (0 deg) assumed: {how}")
    T = ground.camera_pose(est, yaw) if T_world_cam is None else np.asarray(T_world_cam, float)
    objects.with_footprints(kept, camera, T, H, horizon=horizon, hood_top_v=hood_top)
    if road_px is not None:
        blocked = np.zeros((H, W), bool) if hmask is None else hmask.copy()
        for x, y, w, h in (o.box for o in kept):
            blocked[int(y):int(y + h) + 1, int(x):int(x + w) + 1] = True
        if user_walk is not None:
            walk, how = user_walk & ~road_px, "user mask masks/sidewalk"
        else:
            walk, how = road.walkable(image, road.bands(road_px, camera, T, blocked), road_px)
        decide("walkable", round(float(walk.mean()), 4), how)
        mask = np.where(road_px, ROAD, np.where(walk, BAND, 0)).astype(np.uint8)
    centre = None
    if oncoming == "left":
        centre, how = lane_width_m / 2, "ground_plane.oncoming: left (beyond the ego lane's left edge)"
    elif oncoming == "auto":
        centre, how = road.centre_line(image, road_px, camera, T, horizon)
    else:
        how = "ground_plane.oncoming: none"
    decisions.append({"what": "centre_line_m", "value": None if centre is None else round(centre, 2), "reason": how})
    edge, how = road.edge_line(image, road_px, camera, T) if road_px is not None else (None, "no road region")
    decisions.append({"what": "edge_line_m", "value": None if edge is None else round(edge, 2), "reason": how})
    lines, how = lanes.lane_lines(image, road_px, camera, T)
    ego = lane_geometry.ego_lane(lines, lane_geometry.X_REF, lane_width_m)
    if ego is not None and abs((ego[1] - ego[0]) / lane_width_m - 1) > LANE_WIDTH_MISFIT:
        # a lane bounded by two lines, measured in the frame's metric (height, pitch): the
        # vehicles follow the paint, but everything virtual is out of scale with the road
        how += (f"; the ego lane measures {ego[1] - ego[0]:.2f} m for lane_width_m {lane_width_m:g}: "
                f"the camera height ({est.height_m:.2f} m) or pitch ({est.pitch_deg:+.1f} deg) does not fit this frame")
        log.warning("%s: %s", frame_id, how)
    decisions.append({"what": "lane_lines", "value": len(lines), "reason": how})
    fa = FrameAnalysis(frame_id=frame_id, width=W, height=H, camera=est, T_world_cam=T.tolist(),
                       horizon=horizon, hood=[list(map(float, p)) for p in hood] if hood else None,
                       road_mask=f"{frame_id}_road.png" if mask is not None else None,
                       road_direction_deg=None if yaw is None else round(yaw, 2),
                       centre_line_m=None if centre is None else round(centre, 2),
                       edge_line_m=None if edge is None else round(edge, 2), lane_lines=lines, real_objects=kept,
                       placement_max_m=None if limit is None else round(limit, 1),
                       decisions=decisions)
    return fa, mask


def run_analysis(rec, frame_ids: list[str], folder: Path, gp, *, detector_model: Path | None = None,
                 progress: bool = False, on_progress=None) -> dict[str, FrameAnalysis]:
    """Analyse the frames not yet analysed in `folder`; return every frame's analysis.

    Hood (`hood.find_hood`), real road users, then the camera (`camera.estimate_cameras`,
    which scales the height with the real cars found), then road, direction and footprints.
    `gp`: the job's ground_plane section (numbers fix values, "auto" estimates them).
    `on_progress(frames_done, phase)`: called as the phases go (pipeline.outputs.StageProgress)."""
    report = on_progress or (lambda done, phase: None)
    from blendgen.analysis.camera import estimate_cameras
    from blendgen.analysis.hood import find_hood
    from blendgen.recording.frames import is_sequence, read_frames

    folder = Path(folder)
    todo = [f for f in frame_ids if not (folder / f"{f}.json").is_file()]
    before = len(frame_ids) - len(todo)
    if todo:
        t0 = time.process_time()
        detector = objects.load_detector(detector_model)
        report(before, "hood")
        hoods = find_hood(rec, frame_ids, shared=getattr(gp, "stills", "shared") == "shared")  # a video's from many frames
        users = {}
        for n, (fid, image) in enumerate(read_frames(rec, todo, progress=progress, desc="road users")):
            report(before + n, "road users")
            if image is None:
                continue
            users[fid] = not_ego(objects.road_users(image, detector), hood_mask(hoods.get(fid), image.shape[1],
                                                                                 image.shape[0]), *image.shape[1::-1])[0]
        report(before, "camera")
        cams = estimate_cameras(rec, todo, user=gp, hoods=hoods, progress=progress,
                                users={f: [(o.cls, o.box) for o in u] for f, u in users.items()})
        shared = (time.process_time() - t0) / len(todo)
        for n, (fid, image) in enumerate(read_frames(rec, todo)):
            report(before + n, "road, lanes, footprints")
            t1 = time.process_time()
            if image is None:
                continue
            est, horizon = cams[fid]
            # the recording's focal length, also when est.fx re-estimated it: the planner and
            # the renderer project with the recording's camera, and placement must match them
            camera = rec.camera.scaled(image.shape[1], image.shape[0])
            size = (image.shape[1], image.shape[0])
            fa, mask = analyse_frame(image, fid, camera, est, detector, horizon=horizon, hood=hoods.get(fid),
                                     user_road=road.user_mask(rec.root, "road", fid, size),
                                     user_walk=road.user_mask(rec.root, "sidewalk", fid, size), users=users[fid],
                                     oncoming=getattr(gp, "oncoming", "auto"),
                                     lane_width_m=getattr(gp, "lane_width_m", 3.5))
            fa.decisions.append({"what": "cpu_s", "value": round(time.process_time() - t1 + shared, 3),
                                 "reason": "analysis CPU seconds (hood, detector and camera shared per frame)"})
            write_analysis(folder, fa, mask)
            if progress:
                print(f"  analysis {n + 1}/{len(todo)} {fid}: {len(fa.real_objects)} road users, "
                      f"road {'yes' if fa.road_mask else 'no'}, hood {'yes' if fa.hood else 'no'}, "
                      f"h {est.height_m:.2f} m pitch {est.pitch_deg:+.1f} roll {est.roll_deg:+.1f}, direction "
                      f"{fa.road_direction_deg if fa.road_direction_deg is not None else '-'} deg", flush=True)
        for fid in todo:  # a frame that does not decode keeps the camera estimate, and says why
            if not (folder / f"{fid}.json").is_file():
                est, horizon = cams[fid]
                log.warning("%s: frame does not decode: the camera estimate only", fid)
                write_analysis(folder, FrameAnalysis(
                    fid, rec.camera.width, rec.camera.height, est, ground.camera_pose(est).tolist(), horizon,
                    decisions=[{"what": "frame", "value": None, "reason": "does not decode: no road users, road "
                                                                         "or hood, the camera estimate only"}]), None)
    analyses = {f: read_analysis(folder, f) for f in frame_ids}
    if is_sequence(rec) and len(frame_ids) > 1 and any(
            not any(d["what"] == "pose" for d in fa.decisions) for fa in analyses.values()):
        report(len(frame_ids), "ego motion")
        moving_poses(analyses, rec, folder, progress=progress)
    return analyses


def moving_poses(analyses: dict[str, FrameAnalysis], rec, folder: Path, *, progress: bool = False) -> None:
    """Video: the camera moves over the ground plane with the ego motion
    (`egomotion.ground_plane_poses`: road-point odometry, VO heading, GNSS step length;
    the mount's yaw from the vanishing point), so tracks keep one world and a parked car
    recedes as the ego car passes it. Footprints follow each frame's pose; every frame is
    rewritten with the pose decision."""
    from blendgen.analysis.egomotion import ground_track

    # odometry needs consecutive frames: track every recording frame between the first and
    # the last selected one, each with the camera of the nearest analysed frame
    t0 = time.process_time()
    idx = sorted(int(f.lstrip("f")) for f in analyses)
    dense = [rec.frame_id(i) for i in range(idx[0], idx[-1] + 1)]
    near = {f: rec.frame_id(idx[int(np.argmin(np.abs(np.asarray(idx) - int(f.lstrip("f")))))]) for f in dense}
    track = ground_track(rec, dense, {f: analyses[near[f]].camera for f in dense},
                         hoods={f: analyses[near[f]].hood for f in dense}, progress=progress)
    cpu = round((time.process_time() - t0) / len(analyses), 3)
    for fid, fa in analyses.items():
        T = np.asarray(track.poses[fid], float)
        camera = rec.camera.scaled(fa.width, fa.height)
        hood_top = float(np.asarray(fa.hood)[:, 1].min()) if fa.hood else None
        objects.with_footprints(fa.real_objects, camera, T, fa.height, horizon=fa.horizon, hood_top_v=hood_top)
        fa.T_world_cam = T.tolist()
        step = track.steps.get(fid)
        fa.decisions.append({"what": "pose", "value": [round(float(v), 3) for v in T[:3, 3]],
                             "reason": f"video ego motion over the ground plane ({step.status if step else 'first'})"})
        fa.decisions.append({"what": "cpu_s", "value": cpu, "reason": f"ego motion over {len(dense)} frames, "
                                                                       "shared per analysed frame"})
        atomic.write_json(Path(folder) / f"{fid}.json", fa.to_dict())
