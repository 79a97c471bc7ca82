"""The frame analysis cut into per-frame parts and small recording-wide reductions (bpy-free),
so that a long recording is analysed by farm tasks in parallel (pipeline.analysis_tasks)
with the results `stage.run_analysis` gives in one process.

Recording-wide (one task, `calibrate`, from a bounded sample; ~100 frames whatever the length):
- the sample: every frame of a job of up to `N_SAMPLE` frames, else `N_SAMPLE` spread evenly;
- a video's hood (`hood.hood_in_video` over 40 frames spread over the job, as `find_hood`);
- the camera's recording-wide values (`camera.estimate_cameras`): the focal length, the height
  (lane widths in the sample and in 48 frames spread over the recording, else real cars'
  widths), the pitch and roll a frame without its own takes;
- the camera's yaw on its mount (ego motion: the median of the frames' road yaw) and whether
  GNSS covers the drive (its step lengths).
Per frame (parallel):
- `frame_cues`: the frame's hood (stills), real road users (detector), vanishing-point camera;
- `frame_camera`: its camera from the cues of the frames within +-0.5 s (video smoothing) and
  the recording-wide values; then `stage.analyse_frame` (road, bands, lanes, footprints);
- ego motion (video): `egomotion.pair_motions` per pair of frames, then `egomotion.chain_step`
  in order, a few microseconds a frame (the pipeline's only serial chain).
For a job of up to `N_SAMPLE` frames the sample is the job: every value is the one
`run_analysis` computes. For a longer one, the recording-wide values come from the sample
instead of every frame (docs/farm.md says what that costs).
"""

from __future__ import annotations

import math
from dataclasses import asdict
from pathlib import Path

import numpy as np

from blendgen.analysis import ground, objects
from blendgen.analysis.camera import (DEFAULT_HEIGHT_M, DEFAULT_LANE_WIDTH_M, HEIGHT_SAMPLE_FRAMES, SMOOTH_S,
                                      CameraConfig, FrameCamera, _user_value, _weighted_median, angles_from_axes,
                                      estimate_frame, focal_was_guessed, gravity_up, horizon_line, is_sequence,
                                      road_axes)
from blendgen.analysis.model import CameraEstimate, RealObject
from blendgen.geometry import Camera

N_SAMPLE = 48       # frames of the job that give the recording-wide values
SEEK_GAP = 48       # video: frames further apart than this are reached by seeking, not decoding on
VIDEO_HOOD_MIN = 8  # as hood.find_hood: a video of this many job frames has one hood for all


def sample_ids(frame_ids: list[str]) -> list[str]:
    if len(frame_ids) <= N_SAMPLE:
        return list(frame_ids)
    return [frame_ids[i] for i in np.unique(np.linspace(0, len(frame_ids) - 1, N_SAMPLE).round().astype(int))]


def frame_index(fid: str) -> int:
    """The recording index of a frame id (`Recording.frame_id`: f000123)."""
    return int(fid[1:])


class FrameReader:
    """Frames of a recording by index, for a worker that asks for them roughly in order: a
    video decodes on from where it stopped and seeks only over gaps (`SEEK_GAP`); a frame that
    does not decode is None (as read_frames)."""

    def __init__(self, rec):
        self.rec = rec
        self.cap = None
        self.pos = None   # the video index the next read returns

    def __call__(self, i: int):
        from blendgen.errors import UserError
        from blendgen.recording.folder import read_frame

        rec = self.rec
        if rec.video is None:
            try:
                return read_frame(rec, i)
            except UserError:
                return None
        import cv2

        if self.cap is None:
            self.cap = cv2.VideoCapture(str(rec.root / rec.video))
        want = int(rec.frame_index[i])
        if self.pos is None or want < self.pos or want - self.pos > SEEK_GAP:
            self.cap.set(cv2.CAP_PROP_POS_FRAMES, want)
            self.pos = want
        img = None
        while self.pos <= want:
            ok, img = self.cap.read()
            self.pos += 1
            if not ok:
                self.pos = None  # seek next time
                return None
        if rec.camera is not None and img.shape[:2] != (rec.camera.height, rec.camera.width):
            return None
        return img

    def close(self) -> None:
        if self.cap is not None:
            self.cap.release()
            self.cap = None


def frames_at(rec, frame_ids, reader: FrameReader | None = None):
    """Yield (frame_id, BGR or None) in recording order (`FrameReader`)."""
    idx = sorted(frame_index(f) for f in frame_ids)
    own = reader is None
    reader = reader or FrameReader(rec)
    try:
        for i in idx:
            yield rec.frame_id(i), reader(i)
    finally:
        if own:
            reader.close()


# ----------------------------------------------------------------------------- settings

class Settings:
    """The job's ground-plane settings as the camera estimate reads them."""

    def __init__(self, rec, gp):
        self.fixed = {k: _user_value(gp, k) for k in ("camera_height_m", "pitch_deg", "roll_deg")}
        self.lane_w = _user_value(gp, "lane_width_m") or DEFAULT_LANE_WIDTH_M
        self.fit_focal = focal_was_guessed(rec)
        self.need_lines = any(v is None for v in self.fixed.values())
        self.seq = is_sequence(rec)
        self.oncoming = getattr(gp, "oncoming", "auto")
        self.lane_width_m = getattr(gp, "lane_width_m", 3.5)
        self.cfg = CameraConfig()

    def frame_kw(self) -> dict:
        return dict(cfg=self.cfg, roll_prior_deg=self.fixed["roll_deg"] or 0.0, fit_focal=self.fit_focal,
                    lane_width_m=self.lane_w)


def video_hood(rec, frame_ids: list[str]) -> bool:
    return is_sequence(rec) and len(frame_ids) >= VIDEO_HOOD_MIN


# ----------------------------------------------------------------------------- per frame: cues

def frame_cues(image, fid: str, t: float, rec, settings: Settings, detector, hood=None, *, video: bool) -> dict:
    """The per-frame part before the camera: hood (stills: this frame's), the real road users off
    the hood, the frame's vanishing-point camera. JSON-able."""
    from blendgen.analysis.hood import hood_in_still
    from blendgen.analysis.stage import hood_mask, not_ego

    if image is None:
        fc = FrameCamera(None, None, reasons=["frame does not decode"]) if settings.need_lines else None
        return {"frame_id": fid, "t": t, "decoded": False, "hood": hood if video else None, "users": [],
                "camera": None if fc is None else _fc_dict(fc)}
    if not video:
        hood = hood_in_still(image)[0]
    H, W = image.shape[:2]
    users = not_ego(objects.road_users(image, detector), hood_mask(hood, W, H), W, H)[0]
    fc = None
    if settings.need_lines:
        fc = estimate_frame(image, rec.camera, car_boxes=[o.box for o in users if o.cls == "car"], hood=hood,
                            **settings.frame_kw())
    return {"frame_id": fid, "t": t, "decoded": True, "hood": hood, "users": [asdict(o) for o in users],
            "camera": None if fc is None else _fc_dict(fc)}


def _fc_dict(fc: FrameCamera) -> dict:
    return {k: v for k, v in fc.__dict__.items() if k not in ("segments", "labels")}


def fc_of(cue: dict) -> FrameCamera | None:
    return None if cue.get("camera") is None else FrameCamera(**cue["camera"])


def users_of(cue: dict) -> list[RealObject]:
    return [RealObject(**o) for o in cue["users"]]


# ----------------------------------------------------------------------------- recording-wide

def lane_heights_elsewhere(rec, chosen: set[str], hood, settings: Settings) -> list[float]:
    """As camera._lane_heights_elsewhere: heights from lane widths in frames spread over the
    whole recording besides the job's own (read by seeking: a long video is not decoded whole)."""
    idx = np.unique(np.linspace(0, rec.n_frames - 1, HEIGHT_SAMPLE_FRAMES).round().astype(int))
    extra = [rec.frame_id(int(i)) for i in idx if rec.frame_id(int(i)) not in chosen]
    out = []
    for _, im in frames_at(rec, extra):
        if im is not None:
            h = estimate_frame(im, rec.camera, hood=hood, **settings.frame_kw()).height_lanes
            out += [h] if h else []
    return out


def recording_values(rec, per: dict[str, FrameCamera], settings: Settings, hl_elsewhere: list[float]) -> dict:
    """The recording-wide part of `camera.estimate_cameras` from the sample's frame cameras."""
    fxs = [f.fx for f in per.values() if f.fx is not None and f.confidence > 0.3]
    hl = [f.height_lanes for f in per.values() if f.height_lanes] + list(hl_elsewhere)
    hc = [f.height_cars for f in per.values() if f.height_cars]
    out = {"fx": float(np.median(fxs)) if fxs else None,
           "height": [float(np.median(hl)), "lane_width"] if hl else [float(np.median(hc)), "cars"] if hc else None}
    for name, std_name in (("pitch", "pitch_std"), ("roll", "roll_std")):
        allv = [getattr(f, name) for f in per.values()
                if getattr(f, name) is not None and math.isfinite(getattr(f, std_name))]
        out[name + "_median"] = float(np.median(allv)) if allv else None
    return out


def frame_camera(fid: str, t: float, fc: FrameCamera | None, near: list[FrameCamera], rec, settings: Settings,
                 values: dict) -> tuple[CameraEstimate, list | None]:
    """One frame's camera (the loop of `camera.estimate_cameras`): `near`, the frame cameras of the
    job's frames within +-SMOOTH_S of it (itself included; video only), `values` the
    recording-wide ones (`recording_values`)."""
    fixed, seq = settings.fixed, settings.seq
    fc = fc or FrameCamera(None, None)
    fx = values["fx"]
    camera: Camera = rec.camera
    cam = camera if fx is None else Camera(camera.width, camera.height, fx, fx * camera.fy / camera.fx,
                                           camera.cx, camera.cy, list(camera.dist))
    est = CameraEstimate(height_m=DEFAULT_HEIGHT_M, pitch_deg=0.0, roll_deg=0.0, fx=fx, yaw_deg=fc.yaw,
                         confidence=fc.confidence, reasons=list(fc.reasons))
    if fx is not None:
        est.source["fx"] = "vanishing_point"
    near = near if seq else []
    up = gravity_up(rec, t)
    for name, std_name, key in (("pitch", "pitch_std", "pitch_deg"), ("roll", "roll_std", "roll_deg")):
        if fixed[key] is not None:
            setattr(est, key, fixed[key])
            est.source[name] = "user"
            continue
        vals = [(getattr(g, name), g.confidence) for g in near
                if getattr(g, name) is not None and math.isfinite(getattr(g, std_name))]
        own = getattr(fc, name)
        if len(vals) >= 2:       # video: confidence-weighted median over +-0.5 s
            v = np.array(vals)
            value, src = _weighted_median(v[:, 0], v[:, 1] + 1e-6), "smoothed"
            std = max(0.05, float(np.median([getattr(g, std_name) for g in near
                                             if math.isfinite(getattr(g, std_name))])))
        elif own is not None and math.isfinite(getattr(fc, std_name)):
            value, src, std = own, "vanishing_point", max(0.05, getattr(fc, std_name))
        else:
            value, src, std = None, None, None
        if up is not None:
            p_i, r_i, _ = angles_from_axes(np.array([0.0, 0.0, 1.0]), up[0])
            gv = math.degrees(p_i if name == "pitch" else r_i)
            if value is None:
                value, src = gv, "imu"
                est.confidence = max(est.confidence, 1.0 / (1.0 + (up[1] / 1.0) ** 2))
            else:   # inverse-variance average of lines and gravity
                w1, w2 = 1 / std ** 2, 1 / up[1] ** 2
                value, src = (w1 * value + w2 * gv) / (w1 + w2), src + "+imu"
        if value is None:
            med = values[name + "_median"]
            if med is not None:
                value, src = med, "recording_median"
                est.reasons.append(f"{name}: no estimate in this frame, the recording's median")
            else:
                value, src = (fc.roll if name == "roll" and fc.roll is not None else 0.0), "default"
                est.reasons.append(f"{name}: nothing to estimate it from, assumed {value:g} deg")
            est.confidence = 0.0 if src == "default" else min(est.confidence, 0.3)
        setattr(est, key, float(value))
        est.source[name] = src
    if fixed["camera_height_m"] is not None:
        est.height_m, est.source["height"] = fixed["camera_height_m"], "user"
    elif not seq and (fc.height_lanes or fc.height_cars):
        est.height_m, est.source["height"] = ((fc.height_lanes, "lane_width") if fc.height_lanes
                                              else (fc.height_cars, "cars"))
    elif values["height"] is not None:
        est.height_m, est.source["height"] = values["height"][0], values["height"][1]
    else:
        est.height_m, est.source["height"] = DEFAULT_HEIGHT_M, "default"
        est.reasons.append(f"height: no lane markings or cars to scale with, assumed {DEFAULT_HEIGHT_M} m")
    if est.source["pitch"] == "user" and est.source["roll"] == "user":
        est.confidence = 1.0
    U = road_axes(math.radians(est.pitch_deg), math.radians(est.roll_deg), 0.0)[2]
    return est, horizon_line(cam, U)


def smoothing_range(times: np.ndarray, p: int) -> tuple[int, int]:
    """Positions of the job's frames within +-SMOOTH_S of frame p (times sorted)."""
    return (int(np.searchsorted(times, times[p] - SMOOTH_S)),
            int(np.searchsorted(times, times[p] + SMOOTH_S, side="right")))


# ----------------------------------------------------------------------------- ego motion

def dense_ids(rec, job_index: np.ndarray) -> list[str]:
    """Video: every recording frame from the job's first to its last (odometry needs consecutive
    frames), each with the camera of the nearest job frame (`nearest_job`)."""
    return [rec.frame_id(i) for i in range(int(job_index[0]), int(job_index[-1]) + 1)]


def nearest_job(job_index: np.ndarray, i: int) -> int:
    """Position of the job frame nearest to recording frame i (the earlier one on a tie, as
    np.argmin over the analysed frames in stage.moving_poses)."""
    j = int(np.searchsorted(job_index, i))
    if j == 0:
        return 0
    if j >= len(job_index):
        return len(job_index) - 1
    return j - 1 if i - job_index[j - 1] <= job_index[j] - i else j


def road_yaw_raw(est: CameraEstimate) -> float | None:
    """A frame's road yaw (rad) as egomotion._road_yaw reads it, before the 3-frame median."""
    return math.radians(est.yaw_deg) if est.yaw_deg is not None and est.confidence > 0.2 else None


def despiked(raw: list[float | None]) -> float | None:
    """The middle one of three consecutive raw road yaws (None beyond the drive's ends),
    despiked as egomotion._road_yaw: their median when all three exist."""
    near = [v for v in raw if v is not None]
    return float(np.median(near)) if raw[1] is not None and len(near) == 3 else raw[1]


def gnss_track(rec, t_first: float, t_last: float):
    """(east, north) of the GNSS samples relative to the first, when they cover the drive
    [t_first, t_last] (egomotion._gnss_steps), else None."""
    g = rec.gnss
    if len(g) < 2 or t_first < g[0, 0] or t_last > g[-1, 0]:
        return None
    from pymap3d import geodetic2enu

    e, n, _ = geodetic2enu(g[:, 1], g[:, 2], g[:, 3], g[0, 1], g[0, 2], g[0, 3])
    return g[:, 0], np.asarray(e), np.asarray(n)


def gnss_step(track, t0: float, t1: float) -> float | None:
    if track is None:
        return None
    tg, e, n = track
    x, y = np.interp([t0, t1], tg, e), np.interp([t0, t1], tg, n)
    return float(np.hypot(np.diff(x), np.diff(y))[0])


def mount_yaw(rec, job_index: np.ndarray, est_of_pos: dict[int, CameraEstimate]) -> float:
    """The camera's yaw on its mount: the median of the despiked road yaw over the video's
    frames from the job's first to its last, each with the camera of the nearest frame that
    has one (`est_of_pos`: job position -> estimate; all of them for a short job)."""
    from blendgen.analysis.egomotion import mount_yaw_of

    have = np.array(sorted(est_of_pos))
    idx = job_index[have]
    raw = []
    for i in range(int(job_index[0]), int(job_index[-1]) + 1):
        raw.append(road_yaw_raw(est_of_pos[int(have[nearest_job(idx, i)])]))
    n = len(raw)
    yaws = {k: despiked([raw[k - 1] if k else None, raw[k], raw[k + 1] if k + 1 < n else None]) for k in range(n)}
    return mount_yaw_of(yaws)


def horizon_of(est: CameraEstimate, camera: Camera):
    return ground.horizon(camera, ground.camera_pose(est))
