"""The frame analysis cut into per-frame parts and small recording-wide reductions (bpy-free),
so that a long recording is analysed by farm tasks in parallel (pipeline.analysis_tasks)
with the results `stage.run_analysis` gives in one process.

Recording-wide (a few tasks over a bounded sample; ~100 frames whatever the length):
- the sample: every frame of a job of up to `N_SAMPLE` frames, else `N_SAMPLE` spread evenly;
- the hood: a video's from 40 frames spread over the job (`hood.hood_in_video`), stills' the
  consensus of the sample's (`mount.hood_consensus`: one for all, each its own, or none);
- the camera (`camera.recording_camera`): the focal length (`mount.focal_consensus`) and the
  mount (`mount.estimate_mount`: a video's height; stills' height, pitch and roll) from the
  sample's cues, with a video's lane cues from 48 frames outside the job;
- the camera's yaw on its mount (ego motion: the median of the frames' road yaw) and whether
  GNSS covers the drive.
Per frame (parallel):
- `frame_cues`: the frame's hood (stills with their own), real road users (detector),
  `camera.frame_cues` (vanishing points, whole road users, the ego lane's lines);
- its angles from the cues of the frames within +-0.5 s (`camera._smooth`) and its estimate
  (`camera.camera_of_frame`; a still outside the sample: the mount fitted again with it); then
  `stage.analyse_frame` (road, bands, lanes, footprints);
- ego motion (video): `egomotion.pair_motions` per pair of frames, then `egomotion.chain_step`
  in order, a few milliseconds a frame (the pipeline's only serial chain).
For a job of up to `N_SAMPLE` frames the sample is the job: every value is the one
`run_analysis` computes. For a longer one, the recording-wide values come from the sample
instead of every frame, and the sample's frames are smoothed among themselves (docs/farm.md).
"""

from __future__ import annotations

import math
from dataclasses import asdict

import numpy as np

from blendgen import ground
from blendgen.analysis import objects
from blendgen.analysis.camera import (HEIGHT_SAMPLE_FRAMES, SMOOTH_S, CameraSettings, RecordingCamera, _smooth,
                                      camera_of_frame, recording_camera)
from blendgen.analysis.mount import FrameCues, Mount
from blendgen.frame_analysis import CameraEstimate, RealObject
from blendgen.geometry import Camera
from blendgen.recording.frames import is_sequence

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

class Settings(CameraSettings):
    """The job's ground-plane settings as the analysis reads them."""

    def __init__(self, rec, gp):
        super().__init__(rec, gp)
        self.oncoming = getattr(gp, "oncoming", "auto")
        self.lane_width_m = getattr(gp, "lane_width_m", 3.5)


def video_hood(rec, frame_ids: list[str]) -> bool:
    return is_sequence(rec) and len(frame_ids) >= VIDEO_HOOD_MIN


# ----------------------------------------------------------------------------- hood

def stills_hood(polys: dict[str, list | None], camera: Camera, shared: bool = True) -> dict:
    """Stills: what `hood.find_hood` decides from the sample's own hoods: one for all frames
    ("one"), none ("none"), or each frame its own ("own"; always for stills of different cameras)."""
    from blendgen.analysis.hood import CONSENSUS_MIN_FRAMES
    from blendgen.analysis.mount import hood_consensus

    if not shared:
        return {"mode": "own", "hood": None, "reason": "stills of different cameras: each keeps its own hood"}
    if len(polys) < CONSENSUS_MIN_FRAMES:
        return {"mode": "own", "hood": None, "reason": f"{len(polys)} still(s): each keeps its own hood"}
    out, why = hood_consensus(polys, camera.width, camera.height)
    if all(v is None for v in out.values()):
        return {"mode": "none", "hood": None, "reason": why}
    if why.startswith("the same hood edge"):
        return {"mode": "one", "hood": next(iter(out.values())), "reason": why}
    return {"mode": "own", "hood": None, "reason": why}


# ----------------------------------------------------------------------------- per frame: cues

def frame_cues(image, fid: str, t: float, rec, settings: Settings, detector, hood: dict) -> dict:
    """The per-frame part before the camera, JSON-able: the frame's hood (`hood`: the hood task's
    decision), the real road users off it, `camera.frame_cues`."""
    from blendgen.analysis.camera import frame_cues as camera_cues
    from blendgen.analysis.hood import hood_in_still
    from blendgen.analysis.stage import not_ego
    from blendgen.frame_analysis import hood_mask

    if image is None:
        return {"frame_id": fid, "t": t, "decoded": False, "hood": None, "users": [],
                "cues": asdict(FrameCues(t=t, reasons=["frame does not decode"]))}
    poly = hood_in_still(image)[0] if hood["mode"] == "own" else hood["hood"]
    H, W = image.shape[:2]
    users = not_ego(objects.road_users(image, detector), hood_mask(poly, W, H), W, H)[0]
    c = camera_cues(image, rec.camera, t=t, hood=poly, users=[(o.cls, o.box) for o in users], **settings.cue_kw())
    return {"frame_id": fid, "t": t, "decoded": True, "hood": poly, "users": [asdict(o) for o in users],
            "cues": asdict(c)}


def cues_of(cue: dict) -> FrameCues:
    return FrameCues(**cue["cues"])


def users_of(cue: dict) -> list[RealObject]:
    return [RealObject(**o) for o in cue["users"]]


def elsewhere_cue(image, rec, settings: Settings, hood) -> dict | None:
    """A video frame outside the job: its lane cue for the height (`camera._cues_elsewhere`)."""
    from blendgen.analysis.camera import frame_cues as camera_cues

    if image is None:
        return None
    c = camera_cues(image, rec.camera, hood=hood, cfg=settings.cfg, fit_focal=settings.fit_focal,
                    roll_prior_deg=settings.fixed["roll_deg"] or 0.0, lane_width_m=settings.lane_w)
    if c.lane is None or c.pitch is None:
        return None
    return asdict(FrameCues(t=c.t, pitch=c.pitch, roll=c.roll or 0.0, pitch_std=c.pitch_std, roll_std=c.roll_std,
                            lane=c.lane))


# ----------------------------------------------------------------------------- camera

def angles_of(fid: str, cues: dict[str, FrameCues], rec, settings: Settings) -> dict:
    """A frame's pitch and roll (`camera._smooth`) from the cues of the frames within +-0.5 s
    (itself included; `cues` may hold more)."""
    return _smooth(cues, [fid], {f: c.t for f, c in cues.items()}, settings.seq, rec, settings.fixed)[fid]


def recording_doc(sample: dict[str, FrameCues], rec, settings: Settings, elsewhere: list[dict]) -> dict:
    """`camera.recording_camera` over the sample, as JSON (analysis/recording.json's "camera")."""
    angles = _smooth(sample, list(sample), {f: c.t for f, c in sample.items()}, settings.seq, rec, settings.fixed)
    rc = recording_camera(sample, angles, settings, {f"height:{k}": FrameCues(**d) for k, d in enumerate(elsewhere)})
    d = asdict(rc)
    d["angles"] = angles
    return d


def recording_of(doc: dict) -> RecordingCamera:
    d = dict(doc)
    d.pop("angles", None)
    d["mount"] = Mount(**d["mount"])
    d["cues"] = {f: FrameCues(**c) for f, c in d["cues"].items()}
    return RecordingCamera(**d)


def frame_camera(fid: str, fc: FrameCues, a: dict, rc: RecordingCamera, rec) -> tuple[CameraEstimate, list | None]:
    return camera_of_frame(fid, fc, a, rc, rec.camera)


def smoothing_range(times: np.ndarray, p: int) -> tuple[int, int]:
    """Positions of the job's frames within +-SMOOTH_S of frame p (times sorted)."""
    return (int(np.searchsorted(times, times[p] - SMOOTH_S)),
            int(np.searchsorted(times, times[p] + SMOOTH_S, side="right")))


def elsewhere_ids(rec, ids: list[str], settings: Settings) -> list[str]:
    """The recording frames whose lane cues also scale a video's height (none when the job's
    camera height is fixed)."""
    if not (settings.seq and settings.fixed["camera_height_m"] is None):
        return []
    chosen = set(ids)
    idx = np.unique(np.linspace(0, rec.n_frames - 1, HEIGHT_SAMPLE_FRAMES).round().astype(int))
    return [rec.frame_id(int(i)) for i in idx if rec.frame_id(int(i)) not in chosen]


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
