"""How much to trust visual odometry: per-pair measurement noise, and checks of each pair
against the gyro (`assess`): rotation consistency gating, frozen / skipped frames, and
electronically stabilised video, whose per-frame image rotation is then estimated so that
composites follow the image rather than the body.

Noise (`vo_noise`): the first-order covariance of each pair's own fit (`VoResult.rot_cov`,
`dir_cov`: the Sampson residuals' Jacobian and mean square over the RANSAC inliers, or the
linearised Kabsch fit for rotation-only and stationary pairs), so it grows with fewer inliers,
larger residuals, less parallax and a shorter baseline; inflated by the factor the first-order
model underestimates the true error on the synthetic drive (measured: 2.2-3.5x in std, see
docs/sync.md), with floors for what no pixel residual shows (rolling shutter, time offset).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from blendgen import so3
from blendgen.vo import VoResult

# measured on the 60 s synthetic drive (480x270, 5 fps; ORB and KLT): true / predicted std
# was 2.1-2.4 for the rotation and 2.6-3.2 for the direction (median NEES per dof 2.2-7.5)
VO_ROT_INFLATE = 2.5
VO_DIR_INFLATE = 3.5
# floors: what no pixel residual shows. Per pair the rotation has a mean error of ~0.01 deg per
# axis (synthetic drive, ORB and KLT alike): trusted more tightly it is read as a gyro bias of
# ~8e-4 rad/s and tilts the camera (60 s drive: 0.09 -> 0.16 deg with floors of 0.01 / 0.1 deg)
VO_ROT_FLOOR = np.radians(0.08)
VO_DIR_FLOOR = np.radians(0.5)
# ... and with a lens the importer only assumed (a field of view, a pinhole): a larger rotation
# floor, and no direction of travel, whose bias from an unknown principal point and distortion
# (~1 deg per 7 px at f = 400 px) no number of pairs averages out. The real GoPro Karma clip's
# camera against its sea horizon (docs/sync.md; automotive IMU bias priors): VO at the floors
# above 1.90 deg off, without VO 1.20, rotation only at this floor 1.15
VO_ROT_FLOOR_ASSUMED_LENS = np.radians(0.5)
# A lens database's profile of the camera model (`import gopro --lens`) gets the rotation as
# measured but no direction either: the Karma clip with its HERO5 Linear profile (ORB's yaw gain
# against the gyro, 1.000 +- 0.008, confirms it) is 0.55 deg off the horizon with VO rotation, 2.57 with direction
VO_ROT_NO_COV = 0.003             # rad: a pair without a fit covariance (should not happen)


def vo_noise(res: VoResult, lens: str = "calibrated") -> tuple[np.ndarray, np.ndarray | None]:
    """(3x3 rotation covariance, 3x3 direction covariance or None) for a VO pair.
    lens: `Recording.lens_source`. "assumed" (the intrinsics are a guess): a larger rotation
    floor and no direction; "profile" (the camera model's, not this unit's): no direction."""
    rot_floor = VO_ROT_FLOOR_ASSUMED_LENS if lens == "assumed" else VO_ROT_FLOOR
    if res.rot_cov is not None:
        rot = VO_ROT_INFLATE**2 * res.rot_cov + rot_floor**2 * np.eye(3)
    else:
        rot = VO_ROT_NO_COV**2 * np.eye(3)
    if lens != "calibrated" or not res.has_direction or res.u_dir is None:
        return rot, None
    u = np.asarray(res.u_dir, dtype=float)
    tangent = np.eye(3) - np.outer(u, u)
    dcov = res.dir_cov if res.dir_cov is not None else np.radians(0.7) ** 2 * tangent
    return rot, VO_DIR_INFLATE**2 * dcov + VO_DIR_FLOOR**2 * tangent


# ----------------------------------------------------------------------------- gyro checks

GATE_P = 0.999                 # per-pair chi-square gate of VO rotation against the gyro
GYRO_BIAS_STD = 0.01           # rad/s: what the gyro bias may be before the filter knows it
STAB_GAIN = 0.8                # image rotation below this fraction of the body's: smoothed
FOCAL_HINT_GAIN = 0.1          # a rigid image turning > 10 % more or less than the gyro: focal length off
FOCAL_HINT_SIGMA = 4.0         # ... and that many standard errors of the gain away from 1
STAB_MIN_NEES = 3.0            # median normalised VO-gyro disagreement per dof above this: non-rigid
STAB_HIGHPASS_S = 2.0          # s: the stabiliser's correction has no content slower than this (3 s: p90 error 0.40 deg instead of 0.20 on the synthetic shake)
MIN_PAIRS = 10


@dataclass
class TrustReport:
    """What VO is trusted with, per pair and overall (`summary["vo_trust"]`)."""

    flags: list                         # per frame index: None, "gyro_gated", "frozen" or "skipped"
    stabilised: bool = False
    gain: float = float("nan")          # image rotation / body rotation (least squares over pairs)
    nees: float = float("nan")          # median normalised disagreement per dof
    checked: int = 0
    gyro_bias_cam: np.ndarray = field(default_factory=lambda: np.zeros(3))
    correction: np.ndarray | None = None  # (N, 3, 3): image camera in the body's camera, per frame
    correction_std: float = 0.0         # rad: 1-sigma error of a correction (its random walk)
    reason: str = ""

    def summary(self) -> dict:
        c = {k: sum(1 for f in self.flags if f == k) for k in ("gyro_gated", "frozen", "skipped")}
        out = {"pairs_checked": self.checked, **c, "stabiliser_detected": self.stabilised,
               "image_to_gyro_rotation_gain": None if np.isnan(self.gain) else round(float(self.gain), 3),
               "median_nees_per_dof": None if np.isnan(self.nees) else round(float(self.nees), 2),
               "trusted": self.reason}
        if self.correction is not None:
            ang = np.degrees([np.linalg.norm(so3.log(C)) for C in self.correction])
            out["stabiliser_correction_deg"] = {"median": round(float(np.median(ang)), 3),
                                                "max": round(float(np.max(ang)), 3)}
        return out


class GyroIntegrator:
    """The raw gyro (no bias removed) integrated once, so that the body's rotation between
    any two times can be read off cheaply (the time-offset search evaluates many)."""

    def __init__(self, imu: np.ndarray, max_dt: float):
        self.ti = imu[:, 0] if len(imu) else np.zeros(0)
        n = len(self.ti)
        dts = np.diff(self.ti)
        # orientation at every sample (zero-order hold on the midpoint rate)
        self.wm = 0.5 * (imu[1:, 1:4] + imu[:-1, 1:4]) if n >= 2 else np.zeros((0, 3))
        self.Rs = np.empty((n, 3, 3))
        if n:
            self.Rs[0] = np.eye(3)
        for k in range(len(dts)):
            self.Rs[k + 1] = self.Rs[k] @ so3.exp(self.wm[k] * dts[k])
        self.gap_cum = np.concatenate([[0], np.cumsum(dts > max_dt)])

    def _at(self, tq: np.ndarray):
        """(R_b(tq) per time, index of the sample before it; -1 where outside the IMU's span)."""
        tq = np.asarray(tq, dtype=float)
        j = np.searchsorted(self.ti, tq, side="right") - 1
        bad = (j < 0) | (j >= len(self.ti) - 1)
        j = np.where(bad, 0, j)
        R = np.zeros((len(tq), 3, 3))
        if len(self.wm):
            dR = Rotation.from_rotvec(self.wm[j] * (tq - self.ti[j])[:, None]).as_matrix()
            R = self.Rs[j] @ dR
        return R, np.where(bad, -1, j)

    def between(self, ta: np.ndarray, tb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(R_b(ta)^T R_b(tb) per pair, valid mask): invalid outside the IMU's span or across a gap."""
        Ra, ja = self._at(ta)
        Rb, jb = self._at(tb)
        ok = (ja >= 0) & (jb >= 0)
        ok &= self.gap_cum[np.where(ok, jb, 0) + 1] - self.gap_cum[np.where(ok, ja, 0)] == 0
        return np.einsum("nji,njk->nik", Ra, Rb), ok

    def pair_rotations(self, t: np.ndarray) -> list:
        """`gyro_rotations` over consecutive times t: entry k the rotation from t[k-1] to t[k]."""
        t = np.asarray(t, dtype=float)
        out: list = [None] * len(t)
        if len(self.ti) < 2 or len(t) < 2:
            return out
        R, ok = self.between(t[:-1], t[1:])
        for k in np.flatnonzero(ok):
            out[k + 1] = R[k]
        return out


def gyro_rotations(imu: np.ndarray, t: np.ndarray, max_dt: float) -> list:
    """R_b(t[k-1])^T R_b(t[k]) from the raw gyro (no bias removed), None across a gap or
    outside the IMU's time span. Entry 0 is None."""
    if len(imu) < 2 or len(t) < 2:
        return [None] * len(t)
    return GyroIntegrator(imu, max_dt).pair_rotations(t)


def assess(results: list, gyro_R_body: list, R_bc: np.ndarray, t: np.ndarray, gyro_noise: float,
           direction: bool = True) -> TrustReport:
    """Check every VO pair's rotation against the gyro's over the same frame interval and
    decide, over the whole recording, whether the frames move rigidly with the IMU.

    Per pair (chi-square gate with the VO covariance, gyro noise and an unknown bias):
    consistent; `frozen` (the image did not turn while the body did: a repeated or frozen
    frame); `skipped` (the image turned twice what the body did: a dropped frame under a wrong
    time stamp); `gyro_gated` (anything else: moving objects, rolling shutter, a bad fit).
    Overall: if the image turns systematically less than the body (least-squares gain below
    STAB_GAIN) and the disagreement is far above the noise, the video is electronically
    stabilised: VO then says nothing about the body, and the per-frame correction (the image
    camera in the body's camera) is estimated from the VO-gyro difference, high-passed.
    `direction`: whether the filter takes VO's direction of travel too (for the reason line).
    """
    n = len(results)
    rep = TrustReport(flags=[None] * n)
    Rcb = R_bc.T
    rows = []  # (k, w_vo, w_g, Sigma, dt)
    for k in range(1, n):
        r, Rg = results[k], gyro_R_body[k]
        if r is None or Rg is None or not r.has_rotation:
            continue
        dt = float(t[k] - t[k - 1])
        w_g = so3.log(Rcb @ Rg @ R_bc)
        w_vo = so3.log(np.asarray(r.R_c1c2))
        S = vo_noise(r)[0] + np.eye(3) * (gyro_noise**2 * dt)
        rows.append((k, w_vo, w_g, S, dt))
    rep.checked = len(rows)
    if not rows:
        rep.reason = "no VO pair could be checked against the gyro"
        return rep
    W_vo = np.array([r[1] for r in rows])
    W_g = np.array([r[2] for r in rows])
    dts = np.array([r[4] for r in rows])
    # the gyro bias in camera axes, robustly from the pairs (zero-mean stabiliser corrections
    # and VO noise do not move a median); bounded by what a bias can be
    b = np.median((W_g - W_vo) / dts[:, None], axis=0)
    b = np.clip(b, -5 * GYRO_BIAS_STD, 5 * GYRO_BIAS_STD)
    rep.gyro_bias_cam = b
    W_gc = W_g - b * dts[:, None]
    gate = chi2.ppf(GATE_P, 3)
    d2s = []
    for (k, w_vo, _, S, dt), w_g in zip(rows, W_gc):
        S = S + np.eye(3) * (0.2 * GYRO_BIAS_STD * dt) ** 2  # what is left of the bias
        Si = np.linalg.inv(S)
        e = w_vo - w_g
        d2 = float(e @ Si @ e)
        d2s.append(d2)
        if d2 <= gate:
            continue
        turned = float(w_g @ Si @ w_g) > gate
        if turned and float(w_vo @ Si @ w_vo) <= gate:
            rep.flags[k] = "frozen"
        elif turned and float((w_vo - 2 * w_g) @ Si @ (w_vo - 2 * w_g)) <= gate:
            rep.flags[k] = "skipped"
        else:
            rep.flags[k] = "gyro_gated"
    d2s = np.array(d2s)
    rep.nees = float(np.median(d2s) / 3.0)
    gg = float(np.sum(W_gc * W_gc))
    rep.gain = float(np.sum(W_vo * W_gc) / gg) if gg > 0 else float("nan")
    if len(rows) >= MIN_PAIRS and rep.nees > STAB_MIN_NEES and rep.gain < STAB_GAIN:
        rep.stabilised = True
        rep.flags = [None] * n  # the stabiliser explains the disagreement, pair by pair
        rep.correction = _correction(n, rows, W_gc, t)
        # the chained correction is a random walk of the VO rotation noise over half the
        # high-pass window
        sig = np.median([np.sqrt(np.trace(r[3]) / 3.0) for r in rows])
        rep.correction_std = float(sig * np.sqrt(max(1.0, 0.5 * STAB_HIGHPASS_S / np.median(dts))))
        rep.reason = (f"stabilised video: the image turns {rep.gain:.2f}x what the gyro does (median "
                      f"disagreement {rep.nees:.1f}x the noise): per-frame image rotation estimated (1 sigma "
                      f"{np.degrees(rep.correction_std):.2f} deg); VO used for the body after removing it")
    elif len(rows) >= MIN_PAIRS and np.mean(d2s > gate) > 0.5:
        rep.reason = (f"frames do not move rigidly with the IMU ({np.mean(d2s > gate):.0%} of pairs "
                      f"disagree with the gyro, gain {rep.gain:.2f}): those pairs are not used")
    else:
        nb = sum(1 for f in rep.flags if f)
        rep.reason = (f"VO rotation{' + direction' if direction else ''}, {len(rows) - nb} of {len(rows)} "
                      f"checked pairs consistent with the gyro" + (f" ({nb} gated)" if nb else ""))
    # the gain's standard error from each pair's VO covariance (least squares over the pairs)
    gain_se = float(np.sqrt(sum(w @ r[3] @ w for r, w in zip(rows, W_gc)))) / gg if gg > 0 else np.inf
    if not rep.stabilised and len(rows) >= MIN_PAIRS and abs(rep.gain - 1.0) > max(FOCAL_HINT_GAIN,
                                                                                  FOCAL_HINT_SIGMA * gain_se):
        # near the image centre VO's angle is pixels / assumed focal length = true angle x
        # f_true / f_assumed: the gain is the focal length's error (a fisheye read as a pinhole
        # shows the same)
        rep.reason += (f"; the image turns {rep.gain:.2f}x what the gyro does: the camera's focal length "
                       f"is likely {rep.gain:.2f}x calib.yaml's, or the lens is not a pinhole")
    return rep


def _correction(n: int, rows: list, W_gc: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Per frame, the image camera in the body's camera: the chained VO-minus-gyro rotation
    (C_k = R_g^T C_{k-1} R_vo), with everything slower than STAB_HIGHPASS_S removed (the chain's
    random walk and its unknown start: a stabiliser's correction averages out)."""
    C = np.eye(3)
    chain = np.zeros((n, 3))
    by_k = {r[0]: (r[1], w) for r, w in zip(rows, W_gc)}
    for k in range(1, n):
        if k in by_k:
            w_vo, w_g = by_k[k]
            C = so3.exp(-w_g) @ C @ so3.exp(w_vo)
        chain[k] = so3.log(C)
    out = np.empty((n, 3, 3))
    for k in range(n):
        sel = np.abs(t - t[k]) <= 0.5 * STAB_HIGHPASS_S
        out[k] = so3.exp(chain[k] - chain[sel].mean(axis=0))
    return out
