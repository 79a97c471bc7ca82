"""One camera mount from many frames: the recording-wide reduction of the frame analysis
(bpy-free).

The per-frame part (`camera.frame_cues`, `hood.hood_in_still`) leaves each frame's evidence
as plain numbers (`FrameCues`); this module turns the evidence of all frames of one camera
into one mount. Nothing here reads an image.

- `hood_consensus`: stills of one camera share one hood. A hood edge found in most frames
  at the same place is the hood of every frame; found in a minority, it was the road.
- `estimate_mount`: height, pitch and roll of the camera over the road, by one robust least
  squares over every cue of every frame:
    * the vanishing points' pitch and roll per frame (`camera.estimate_frame`), each with its
      fitted standard deviation and a floor `VP_SYS_DEG` (lines along the road and buildings
      can disagree with the plane the road users stand on);
    * real road users standing on the road: a car seen from behind or ahead is about
      `CAR_WIDTH_M` wide and its box's bottom row is its rear wheels' contact `CAR_OVERHANG_M`
      beyond its rear face; any car is about `CAR_HEIGHT_M` tall, a standing person
      `PERSON_HEIGHT_M`. Each object's box gives the height the camera must have at the frame's
      pitch and roll, so objects at different distances also pin the horizon (near and far
      objects only agree at the right one);
    * the ego lane's two painted lines (`lane_geometry.ego_lane`): their spacing is a lane width,
      `LANE_WIDTH_M` with a spread that admits narrow urban lanes and wide arterials;
    * a weak prior on the height (`HEIGHT_PRIOR_M`), so a frame set with no cue at all still
      gets a value, and an uncertainty that says so.
  Stills: one pitch, roll and height for the camera plus a deviation per frame with a prior
  `FRAME_DEV_DEG`: a frame moves away from the mount only as far as its own evidence is
  strong (a stopped or braking car pitches, a cambered road rolls). Video: each frame's pitch
  and roll are given (smoothed over time by the caller); the reduction fits the height.
  Every residual is normalised by its standard deviation; the measurements' loss is Cauchy's
  (a vanishing point of car rears, a parked van taken for a car or a kerb taken for a lane line
  costs little), the priors' is Gaussian.

The result carries 1-sigma uncertainties from the fit (`Mount.frame_pitch_std` ...), which
the analysis turns into how far objects may stand (`placement_limit`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import lil_matrix
from scipy.spatial.transform import Rotation

from blendgen.geometry import R_world_cam_from_ypr

# cue models (external knowledge, not tuned on the zoo)
CAR_WIDTH_M = 1.85       # body width of the passenger-car fleet seen from behind (sedans 1.8, SUVs 1.9)
MIRROR_WIDTH_M = 2.08    # across the door mirrors (a Camry: 1.84 body, 2.08 mirrors) ...
MIRROR_AHEAD_M = 2.0     # ... which stand this far ahead of the rear face: beyond ~16 m they set the box's width
CAR_OVERHANG_M = 0.9     # rear face to rear wheels' ground contact: the box's bottom row is there
CAR_HEIGHT_M = 1.65      # sedans 1.45, SUVs, pickups and vans (most of the US fleet) 1.7-1.9
PERSON_HEIGHT_M = 1.70
SIGMA_LOG = {"car_width": 0.08, "car_height": 0.13, "person": 0.08, "lane": 0.10, "lane_known": 0.04}
LANE_WIDTH_M = 3.4       # US 10-12 ft, European 2.75-3.75 m: centre of the range
HEIGHT_PRIOR_M, HEIGHT_PRIOR_LOG = 1.5, 0.25    # dashcams 1.1-1.4 m, roof rigs 1.5-1.9 m (1.5: the job default)
MIN_DEPRESSION = 0.008   # tan: a contact point less than ~0.5 deg below the horizon says little
MIN_BOX_PX = 14          # smaller boxes are mostly detector slack
REAR_VIEW_ASPECT = 1.45  # w/h of a car box seen from behind or ahead (side views: ~2.5-3)
REAR_VIEW_BEARING = 0.3  # tan of the bearing: cars near the optical axis run along the road
# fusion constants (tuned leave-one-rig-out on the camera zoo: benchmarks/analysis/bench_camera.py --zoo)
SIZE_SCALE = 1.0         # the car and prior-lane sizes as the detector and the paint finder see them (grid 1.0-1.2)
VP_SYS_DEG = 2.0         # floor on a vanishing point's pitch/roll error against the road users' plane (0.3-2)
FRAME_DEV_DEG = 0.25     # how far a still's pitch or roll may wander from the mount, prior sigma (0.25-1)


@dataclass
class FrameCues:
    """One frame's evidence on the camera mount, the per-frame part's output (plain numbers).

    Angles in degrees; pixels are undistorted pinhole pixels of the recording's camera."""

    t: float = 0.0
    pitch: float | None = None          # vanishing points (None: no estimate)
    roll: float | None = None
    pitch_std: float = float("inf")
    roll_std: float = float("inf")      # inf: roll came from the prior
    yaw: float | None = None
    fx: float | None = None             # the focal length when this frame alone pins it (< 3 %)
    fx_fit: float | None = None         # the focal length its lines fit at any precision ...
    fx_log_std: float = float("inf")    # ... and the standard deviation of log fx
    confidence: float = 0.0
    reasons: list[str] = field(default_factory=list)
    # road users standing on the road: (cls, [[u, v_bottom] centre, left, right], [u, v_top]) each
    objects: list[tuple[str, list[list[float]]]] = field(default_factory=list)
    # the ego lane's two lines, two pixels each: [[[u, v], [u, v]], [[u, v], [u, v]]]
    lane: list[list[list[float]]] | None = None


@dataclass
class Mount:
    height_m: float
    height_std_log: float
    pitch_deg: float                    # the mount (stills) or the median over frames (video)
    roll_deg: float
    frame_pitch: dict[str, float]
    frame_roll: dict[str, float]
    frame_pitch_std: dict[str, float]
    frame_roll_std: dict[str, float]
    cues: dict[str, int]                # cue kind -> how many took part
    source: dict[str, str]              # quantity -> how it was decided
    reasons: list[str] = field(default_factory=list)


# ----------------------------------------------------------------------------- hood

def hood_consensus(polys: dict[str, list | None], width: int, height: int, *, agree: float = 0.02,
                   share: float = 0.5) -> tuple[dict[str, list | None], str]:
    """One hood for stills of one camera. The frames whose hood edges agree with the
    per-column median (median |row difference| <= agree x height) make it, their median, when
    they are at least `share` of all frames (and 2): every frame gets it. Found in no more than
    `share` of the frames, it was the road (a shadow, a kerb sits elsewhere in every frame; a
    hood does not move): none anywhere. Found in most frames but at different places (stills
    of several cars imported together): each frame keeps its own."""
    n = len(polys)
    found = {f: p for f, p in polys.items() if p is not None}
    if len(found) < 2 or len(found) <= share * n:
        return {f: None for f in polys}, (f"a hood edge in {len(found)} of {n} frames: a camera's hood is in most of "
                                           "its frames, so this was the road")
    u = np.linspace(0, width - 1, 65)
    edges = np.array([np.interp(u, np.asarray(p[:-2])[:, 0], np.asarray(p[:-2])[:, 1]) for p in found.values()])
    med = np.median(edges, axis=0)
    inl = np.median(np.abs(edges - med), axis=1) <= agree * height
    if inl.sum() < max(2, math.ceil(share * n)):
        return dict(polys), (f"a hood edge in {len(found)} of {n} frames at {int(inl.sum())} or fewer agreeing "
                             "places: each frame keeps its own (stills of several cars?)")
    edge = np.median(edges[inl], axis=0)
    poly = [[float(a), float(min(b, height - 1))] for a, b in zip(u, edge)]
    poly += [[width - 1.0, height - 1.0], [0.0, height - 1.0]]
    return {f: poly for f in polys}, f"the same hood edge in {int(inl.sum())} of {n} frames (median of those)"


# ----------------------------------------------------------------------------- focal length

FX_FRAME_MAX_LOG_STD = 0.2   # a frame's focal length fit counts when known to 20 % ...
FX_MIN_FRAMES = 5            # ... in at least this many frames ...
FX_MAX_LOG_STD = 0.03        # ... whose median is known to 3 % (MAD / sqrt(n))


def focal_consensus(frames: dict[str, FrameCues]) -> tuple[float | None, str]:
    """One camera's focal length from many stills' vanishing points when the import guessed
    the field of view: a frame whose road and vertical vanishing points both lie in reach pins
    it (kept when known to 3 %); otherwise the median over frames each known to 20 %, when
    enough of them agree. A nearly level camera's vertical vanishing point is far away: one
    frame rarely pins f, many frames can."""
    own = [c.fx for c in frames.values() if c.fx is not None and c.confidence > 0.3]
    if own:
        return float(np.median(own)), f"from {len(own)} frame(s) that pin it (< 3 %)"
    lf = np.log([c.fx_fit for c in frames.values() if c.fx_fit and c.fx_log_std < FX_FRAME_MAX_LOG_STD])
    if len(lf) < FX_MIN_FRAMES:
        return None, f"{len(lf)} frame(s) fit the focal length to 20 % (need {FX_MIN_FRAMES}): the import's value kept"
    med = float(np.median(lf))
    sd = 1.4826 * float(np.median(np.abs(lf - med))) / math.sqrt(len(lf))
    if sd > FX_MAX_LOG_STD:
        return None, f"{len(lf)} frames disagree on the focal length (+-{sd:.0%}): the import's value kept"
    return float(math.exp(med)), f"median of {len(lf)} frames (+-{sd:.1%})"


# ----------------------------------------------------------------------------- mount

_R_BODY_CAM = R_world_cam_from_ypr(0.0, 0.0, 0.0)


def _axes(pitch_deg: np.ndarray, roll_deg: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rows F, L, U of the road frame in camera coordinates (yaw 0): the matrices of
    `geometry.R_world_cam_from_ypr`, all frames at once."""
    p, r = np.radians(np.atleast_1d(pitch_deg)), np.radians(np.atleast_1d(roll_deg))
    R = Rotation.from_euler("ZYX", np.column_stack([np.zeros_like(p), -p, r])).as_matrix()
    return R @ _R_BODY_CAM


class _Cues:
    """Every object and lane cue of the frames as arrays, for residuals at any pitch and roll."""

    def __init__(self, frames: list[FrameCues], K: np.ndarray):
        Kinv = np.linalg.inv(K)
        fi, kind, rays = [], [], []
        for i, fc in enumerate(frames):
            for cls, pts in fc.objects:
                (ub, vb), (ul, _), (ur, _), (ut, vt) = pts
                w, h = ur - ul, vb - vt
                if min(w, h) < MIN_BOX_PX:
                    continue
                if cls == "car":
                    bearing = abs((ub - K[0, 2]) / K[0, 0])
                    k = "car_width" if w / h < REAR_VIEW_ASPECT and bearing < REAR_VIEW_BEARING else "car_height"
                elif cls == "person" and w / h < 0.6:
                    k = "person"
                else:
                    continue
                fi.append(i)
                kind.append(k)
                rays.append(np.c_[np.asarray(pts, float), np.ones(4)] @ Kinv.T)
            if fc.lane is not None:
                fi.append(i)
                kind.append("lane")
                rays.append(np.c_[np.asarray(fc.lane, float).reshape(4, 2), np.ones(4)] @ Kinv.T)
        self.frame = np.asarray(fi, int)
        self.kind = np.asarray(kind)
        self.rays = np.asarray(rays, float).reshape(-1, 4, 3)
        self.sigma = np.array([SIGMA_LOG[k] for k in kind])

    def log_heights(self, axes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(log of the camera height each cue implies, valid) for per-frame road axes (n, 3, 3)."""
        if not len(self.frame):
            return np.zeros(0), np.zeros(0, bool)
        A = axes[self.frame]                                   # (m, 3, 3)
        proj = np.einsum("mpk,mak->mpa", self.rays, A)         # (m, 4 points, F L U)
        fwd, lat, up = proj[..., 0], proj[..., 1], proj[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            dep = -up / fwd                                    # tan of the depression below the horizon
            out = np.full(len(self.kind), np.nan)
            car_w = self.kind == "car_width"
            bear = lat / fwd
            wang = bear[:, 1] - bear[:, 2]
            # the rear face's distance: the box is as wide as the body or, farther away, the mirrors
            d = np.maximum(CAR_WIDTH_M / wang[car_w], MIRROR_WIDTH_M / wang[car_w] - MIRROR_AHEAD_M)
            out[car_w] = np.log((d + CAR_OVERHANG_M) * dep[car_w, 0])
            hang = dep[:, 0] - dep[:, 3]
            for k, size in (("car_height", CAR_HEIGHT_M), ("person", PERSON_HEIGHT_M)):
                m = self.kind == k
                out[m] = np.log(size * dep[m, 0] / hang[m])
            lane = self.kind == "lane"
            if lane.any():  # the two lines on the ground under a camera 1 m high; their spacing
                g = np.stack([fwd[lane], lat[lane]], -1) / -up[lane][..., None]     # (l, 4, 2)
                a1, a2, b1, b2 = g[:, 0], g[:, 1], g[:, 2], g[:, 3]
                d = a2 - a1
                mid = 0.5 * (b1 + b2)
                sep = np.abs(d[:, 0] * (mid - a1)[:, 1] - d[:, 1] * (mid - a1)[:, 0]) / np.linalg.norm(d, axis=1)
                out[lane] = np.log(LANE_WIDTH_M / sep)
            valid = np.isfinite(out) & (dep[:, 0] > MIN_DEPRESSION) & np.all(fwd > 0, axis=1)
        return np.where(valid, out, 0.0), valid


def estimate_mount(frames: dict[str, FrameCues], K: np.ndarray, *, sequence: bool = False,
                   fixed: dict[str, float | None] | None = None, vp_sys_deg: float | None = None,
                   frame_dev_deg: float | None = None, size_scale: float | None = None,
                   lane_width_m: float | None = None) -> Mount:
    """The camera's height, pitch and roll from all frames' cues (module doc). `fixed`: the
    user's values (camera_height_m, pitch_deg, roll_deg; None or absent: estimate). Video
    (`sequence`): each frame's `pitch` and `roll` are taken as given (smoothed by the caller;
    a frame without one must have been filled) and only the height is fitted. `lane_width_m`:
    the road's lane width when the user knows it (the lanes then scale the height exactly,
    SIGMA_LOG["lane_known"]); otherwise the prior LANE_WIDTH_M. `size_scale` (default
    SIZE_SCALE) multiplies the sizes of the cars and the prior lane, not people's."""
    fixed = {k: v for k, v in (fixed or {}).items() if v is not None}
    vp_sys_deg = VP_SYS_DEG if vp_sys_deg is None else vp_sys_deg
    frame_dev_deg = FRAME_DEV_DEG if frame_dev_deg is None else frame_dev_deg
    log_scale = math.log(SIZE_SCALE if size_scale is None else size_scale)
    ids = list(frames)
    fc = [frames[f] for f in ids]
    n = len(ids)
    cues = _Cues(fc, np.asarray(K, float))
    reasons: list[str] = []
    has_p = np.array([c.pitch is not None and math.isfinite(c.pitch_std) for c in fc])
    has_r = np.array([c.roll is not None and math.isfinite(c.roll_std) for c in fc])
    vp_p = np.array([c.pitch if h else 0.0 for c, h in zip(fc, has_p)])
    vp_r = np.array([c.roll if h else (c.roll or 0.0) for c, h in zip(fc, has_r)])
    sd_p = np.hypot([c.pitch_std if h else 1.0 for c, h in zip(fc, has_p)], vp_sys_deg)
    sd_r = np.hypot([c.roll_std if h else 1.0 for c, h in zip(fc, has_r)], vp_sys_deg)

    free_p = "pitch_deg" not in fixed and not sequence
    free_r = "roll_deg" not in fixed and not sequence
    free_h = "camera_height_m" not in fixed
    p0 = fixed.get("pitch_deg", float(np.median(vp_p[has_p])) if has_p.any() else 0.0)
    r0 = fixed.get("roll_deg", float(np.median(vp_r[has_r])) if has_r.any() else float(np.median(vp_r)))
    if sequence:  # the caller's per-frame angles (or the fixed values)
        base_p = np.full(n, fixed["pitch_deg"]) if "pitch_deg" in fixed else np.array([c.pitch or 0.0 for c in fc])
        base_r = np.full(n, fixed["roll_deg"]) if "roll_deg" in fixed else np.array([c.roll or 0.0 for c in fc])
    else:
        base_p, base_r = np.zeros(n), np.zeros(n)
    h0 = math.log(fixed.get("camera_height_m", HEIGHT_PRIOR_M))

    # parameters: [pitch, roll, log h] (those free), then per-frame pitch and roll deviations (stills)
    names = (["p"] if free_p else []) + (["r"] if free_r else []) + (["h"] if free_h else [])
    ndev_p = n if free_p else 0
    ndev_r = n if free_r else 0
    npar = len(names) + ndev_p + ndev_r

    def unpack(x):
        g = dict(zip(names, x[:len(names)]))
        p = g.get("p", p0)
        r = g.get("r", r0)
        lh = g.get("h", h0)
        dp = x[len(names):len(names) + ndev_p] if ndev_p else np.zeros(n)
        dr = x[len(names) + ndev_p:] if ndev_r else np.zeros(n)
        return p, r, lh, dp, dr

    def angles(x):
        p, r, lh, dp, dr = unpack(x)
        if sequence:
            return base_p, base_r, lh
        return p + dp, r + dr, lh

    # which cues are usable: decided once at the start values (a cut at a moving boundary would
    # make the loss jump between iterations)
    x0 = np.zeros(npar)
    for i, nm in enumerate(names):
        x0[i] = {"p": p0, "r": r0, "h": h0}[nm]
    pa, ra, _ = angles(x0)
    # the cue models' sizes: cars and the prior lane scaled (SIZE_SCALE), people not, a lane
    # width the user gave exactly
    lane = cues.kind == "lane"
    shift = np.where(cues.kind == "person", 0.0, log_scale)
    if lane_width_m is not None:
        shift = np.where(lane, math.log(lane_width_m / LANE_WIDTH_M), shift)
        cues.sigma = np.where(lane, SIGMA_LOG["lane_known"], cues.sigma)
    lh_cue, valid = cues.log_heights(_axes(pa, ra))
    lh_cue = lh_cue + shift
    if free_h and valid.any():  # start from the cues' median, not the prior
        x0[names.index("h")] = float(np.median(lh_cue[valid]))
    sig = cues.sigma[valid]
    shift = shift[valid]
    cue_frame = cues.frame[valid]

    def residuals(x):
        pf, rf, lh = angles(x)
        out = []
        if free_p:
            out.append(((pf - vp_p) / sd_p)[has_p])
            out.append(x[len(names):len(names) + n] / frame_dev_deg)
        if free_r:
            out.append(((rf - vp_r) / sd_r)[has_r])
            out.append(x[len(names) + ndev_p:] / frame_dev_deg)
        if free_h:
            out.append(np.array([(lh - math.log(HEIGHT_PRIOR_M)) / HEIGHT_PRIOR_LOG]))
        if valid.any():
            lc, _ = cues.log_heights(_axes(pf, rf))
            out.append((lh - lc[valid] - shift) / sig)
        return np.concatenate(out) if out else np.zeros(1)

    # rows of the priors in the residual vector (the rest are measurements)
    prior_rows, k = [], 0
    if free_p:
        k += int(has_p.sum())
        prior_rows += list(range(k, k + n))
        k += n
    if free_r:
        k += int(has_r.sum())
        prior_rows += list(range(k, k + n))
        k += n
    if free_h:
        prior_rows.append(k)
    if npar:
        sparsity = _sparsity(names, n, has_p, has_r, free_p, free_r, free_h, cue_frame)
        # every measurement is Cauchy (a vanishing point of car rears, a van taken for a car, a
        # kerb taken for a lane line cost little), the priors are Gaussian: a still moves off
        # the mount where its own lines say so within about FRAME_DEV_DEG, not by degrees
        robust = np.ones(sparsity.shape[0], bool)
        robust[prior_rows] = False

        def loss(z):
            rho = np.where(robust, np.log1p(z), z)
            d1 = np.where(robust, 1.0 / (1.0 + z), 1.0)
            d2 = np.where(robust, -1.0 / (1.0 + z) ** 2, 0.0)
            return np.stack([rho, d1, d2])

        sol = least_squares(residuals, x0, loss=loss, method="trf",  # one unknown: scipy's sparse 2-D subspace fails
                            jac_sparsity=sparsity if len(x0) > 1 else None,
                            x_scale="jac", xtol=1e-5, ftol=1e-6, max_nfev=60)
        x = sol.x
        J = sol.jac.toarray() if hasattr(sol.jac, "toarray") else np.asarray(sol.jac)
        # covariance of the robustly weighted problem: the loss' weights at the solution
        w = loss(sol.fun ** 2)[1]
        try:
            cov = np.linalg.pinv((J * w[:, None]).T @ J)
        except np.linalg.LinAlgError:
            cov = np.eye(npar)
    else:
        x, cov = x0, np.zeros((0, 0))
    p, r, lh, dp, dr = unpack(x)
    pf, rf, _ = angles(x)

    def var_sum(i_glob, i_dev):
        idx = [j for j in (i_glob, i_dev) if j is not None]
        e = np.zeros(npar)
        e[idx] = 1.0
        return float(e @ cov @ e) if idx else 0.0

    ip = names.index("p") if free_p else None
    ir = names.index("r") if free_r else None
    std_p, std_r = {}, {}
    for i, f in enumerate(ids):
        if sequence:
            std_p[f] = fc[i].pitch_std if math.isfinite(fc[i].pitch_std) else 3.0
            std_r[f] = fc[i].roll_std if math.isfinite(fc[i].roll_std) else 3.0
        else:
            std_p[f] = 0.0 if not free_p else math.sqrt(max(var_sum(ip, len(names) + i), 0.0))
            std_r[f] = 0.0 if not free_r else math.sqrt(max(var_sum(ir, len(names) + ndev_p + i), 0.0))
    h_std = math.sqrt(max(float(cov[names.index("h"), names.index("h")]), 0.0)) if free_h else 0.0
    used = {k: int(np.count_nonzero(valid & (cues.kind == k))) for k in ("car_width", "car_height", "person", "lane")}
    used["vanishing_points"] = int(has_p.sum())
    if free_h and not valid.any():
        reasons.append(f"height: no lane lines, cars or people to scale with in {n} frame(s): the prior "
                       f"{HEIGHT_PRIOR_M} m (+-{HEIGHT_PRIOR_LOG:.0%})")
    kinds = [name for name, ks in (("lanes", ("lane",)), ("cars", ("car_width", "car_height")), ("people", ("person",)))
             if any(used[k] for k in ks)]
    source = {"height": "user" if not free_h else ("+".join(kinds) if kinds else "default"),
              "pitch": "user" if "pitch_deg" in fixed else ("smoothed" if sequence else "mount"),
              "roll": "user" if "roll_deg" in fixed else ("smoothed" if sequence else "mount")}
    return Mount(height_m=float(math.exp(lh)), height_std_log=h_std, pitch_deg=float(np.median(pf) if sequence else p),
                 roll_deg=float(np.median(rf) if sequence else r),
                 frame_pitch={f: float(v) for f, v in zip(ids, pf)}, frame_roll={f: float(v) for f, v in zip(ids, rf)},
                 frame_pitch_std=std_p, frame_roll_std=std_r, cues=used, source=source, reasons=reasons)


def _sparsity(names, n, has_p, has_r, free_p, free_r, free_h, cue_frame):
    """Which parameter each residual depends on (residual order of `estimate_mount`)."""
    g = len(names)
    ndev_p = n if free_p else 0
    rows = []
    if free_p:
        rows += [[names.index("p"), g + i] for i in np.flatnonzero(has_p)]
        rows += [[g + i] for i in range(n)]
    if free_r:
        rows += [[names.index("r"), g + ndev_p + i] for i in np.flatnonzero(has_r)]
        rows += [[g + ndev_p + i] for i in range(n)]
    if free_h:
        rows.append([names.index("h")])
    for i in cue_frame:
        cols = [names.index(k) for k in ("p", "r", "h") if k in names]
        cols += ([g + i] if free_p else []) + ([g + ndev_p + i] if free_r else [])
        rows.append(cols)
    S = lil_matrix((max(len(rows), 1), g + ndev_p + (n if free_r else 0)), dtype=int)
    for k, cols in enumerate(rows):
        S[k, cols] = 1
    return S


# ----------------------------------------------------------------------------- placement

FLOAT_MAX_M = 0.3        # an object's contact may be this far above or below the real road (1 sigma): a tyre's radius
ROAD_HALF_M = 4.0        # objects stand within about this of the camera's line of travel (a roll error tilts them)
SCALE_MAX = 0.20         # a camera height this uncertain (1 sigma, relative) draws every object at an unknown scale


def placement_limit(pitch_std_deg: float | None, roll_std_deg: float | None, height_std_rel: float | None,
                    hfov_deg: float) -> tuple[float | None, str]:
    """How far from the camera an object may stand (m; None: no limit) and why. A pitch error
    e puts an object d metres away d*tan(e) above or below the real road where it stands in
    the image, a roll error r by its lateral offset (<= ROAD_HALF_M, and within the view)
    times tan(r): objects stay within FLOAT_MAX_M of the road out to
    (FLOAT_MAX_M - y tan r) / tan e. A height uncertain by more than SCALE_MAX makes every
    object's size uncertain: none."""
    if height_std_rel is not None and height_std_rel > SCALE_MAX:
        return 0.0, (f"the camera height is uncertain by +-{height_std_rel:.0%} (over {SCALE_MAX:.0%}): "
                     "objects would be drawn at an unknown scale")
    e = math.tan(math.radians(pitch_std_deg or 0.0))
    r = math.tan(math.radians(roll_std_deg or 0.0))
    y = ROAD_HALF_M
    if e <= 0:
        if r * y < FLOAT_MAX_M:
            return None, "camera pitch known"
        lim = FLOAT_MAX_M / (r * math.tan(math.radians(hfov_deg / 2)))  # only the roll: the lateral offset in view
    else:
        lim = max(FLOAT_MAX_M - y * r, 0.0) / e
        lim = max(lim, 0.0)
    return lim, (f"pitch +-{pitch_std_deg or 0:.2f} deg, roll +-{roll_std_deg or 0:.2f} deg (1 sigma): beyond {lim:.0f} m "
                 f"an object could float or sink more than {FLOAT_MAX_M:g} m")
