"""Camera-IMU time offset from the data (calib.yaml `timeshift_cam_imu: auto`).

Kalibr's convention: t_imu = t_cam + shift. Each VO pair's rotation (frames k-1, k) is the
body's rotation over [t_cam[k-1] + shift, t_cam[k] + shift] seen in the camera's axes; with the
wrong shift the gyro is integrated over a window displaced by the error d, and the two differ
by about (w(t_k) - w(t_k-1)) d: only *changes* of the angular rate between frames show the
offset (shake, turning in and out), a constant rate or no rotation does not. Rotation only,
so neither scale nor position nor the filter enters.

The cost of a candidate shift is the negative log-likelihood of the VO-minus-gyro rotation
vectors under a Huber kernel, with the gyro bias (Huber M-estimate of the difference per
second) refitted at each candidate and the noise scale measured robustly (MAD) once. It is
minimised on a grid of a quarter frame interval over calib +- search, then on a finer grid
about the best point, each refined by a parabola (`latency.profile_latency`). The 1-sigma is
the larger of the curvature's (independent pairs) and a delete-one-block jackknife's (which
sees correlated errors and model misfit). Pairs the trust check flags (frozen, skipped,
gyro-gated) are left out. The estimate replaces the calib value only when it is determined
(enough pairs, a curved cost, 1-sigma <= MAX_STD_S, not at the search limit); otherwise the
calib value is kept and the reason reported.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from blendgen.sync.latency import profile_latency
from blendgen.sync.vo_trust import GYRO_BIAS_STD, GyroIntegrator

SEARCH_S = 0.1          # default half-width of the search about the calib value
MAX_STD_S = 0.005       # a 1-sigma above this: undetermined, the calib value is kept
MIN_PAIRS = 20
HUBER_C = 2.0           # residual components beyond 2 sigma count linearly
JACKKNIFE_BLOCKS = 8    # contiguous blocks of pairs left out one at a time for the 1-sigma


@dataclass
class TimeOffset:
    """How the camera-IMU time offset used by sync was found (`summary["camera_imu_time_offset"]`)."""

    shift_s: float                      # used: t_imu = t_cam + shift
    calib_s: float                      # calib.yaml's value
    method: str                         # "calib.yaml", "estimated" or "calib.yaml (estimate undetermined)"
    estimate_s: float | None = None     # the minimum of the cost, even when not used
    std_s: float | None = None          # 1-sigma: the larger of the two below; None when the cost is flat
    std_curvature_s: float | None = None  # from the cost's curvature (independent pairs)
    std_jackknife_s: float | None = None  # delete-one-block jackknife (correlated errors, model misfit)
    pairs: int = 0
    reason: str = ""
    residual_calib_deg: float | None = None  # RMS VO-gyro rotation difference per pair at the calib value
    residual_used_deg: float | None = None   # the same at the shift used
    rate_change_dps: float | None = None     # RMS change of the angular rate between pairs (what observes it)
    profile: list = field(default_factory=list)

    def summary(self) -> dict:
        r = lambda x, n: None if x is None else round(float(x), n)  # noqa: E731
        return {"shift_s": r(self.shift_s, 5), "calib_s": r(self.calib_s, 5), "method": self.method,
                "estimate_s": r(self.estimate_s, 5), "std_s": r(self.std_s, 5),
                "std_curvature_s": r(self.std_curvature_s, 5), "std_jackknife_s": r(self.std_jackknife_s, 5),
                "pairs": self.pairs,
                "reason": self.reason, "residual_calib_deg": r(self.residual_calib_deg, 4),
                "residual_used_deg": r(self.residual_used_deg, 4), "rate_change_dps": r(self.rate_change_dps, 2),
                "profile": [[round(a, 5), round(b, 3)] for a, b in self.profile]}


def describe(s: dict) -> str:
    """One line for the command."""
    sh = s["shift_s"]
    if s["method"] == "estimated":
        out = (f"camera-IMU time offset {sh * 1e3:+.1f} +- {s['std_s'] * 1e3:.1f} ms estimated from {s['pairs']} "
               f"VO-gyro rotation pairs (calib.yaml {s['calib_s'] * 1e3:+.1f} ms)")
    elif s["method"] == "calib.yaml":
        return f"camera-IMU time offset {sh * 1e3:+.1f} ms from calib.yaml (timeshift_cam_imu: auto estimates it)"
    else:
        out = f"camera-IMU time offset {sh * 1e3:+.1f} ms from calib.yaml: not estimated, {s['reason']}"
    if s.get("residual_calib_deg") is not None and s.get("residual_used_deg") is not None:
        out += (f"; VO-gyro rotation residual {s['residual_calib_deg']:.3f} -> {s['residual_used_deg']:.3f} deg RMS"
                if s["method"] == "estimated" else f"; VO-gyro rotation residual {s['residual_used_deg']:.3f} deg RMS")
    return out


class _Pairs:
    """The VO pairs used and their gyro rotation at any shift."""

    def __init__(self, results, gyro: GyroIntegrator, t_cam, R_bc, flags, lo: float, hi: float):
        self.gyro, self.R_bc = gyro, R_bc
        t_cam = np.asarray(t_cam, dtype=float)
        ks = [k for k in range(1, len(results)) if results[k] is not None and results[k].has_rotation
              and (flags is None or flags[k] is None)]
        ks = np.array(ks, dtype=int)
        if len(ks):  # the set must not change with the shift: every interval covered at both ends
            ok = gyro.between(t_cam[ks - 1] + lo, t_cam[ks] + lo)[1] & gyro.between(t_cam[ks - 1] + hi,
                                                                                   t_cam[ks] + hi)[1]
            ks = ks[ok]
        self.k = ks
        self.ta, self.tb = t_cam[ks - 1], t_cam[ks]
        self.dt = self.tb - self.ta
        self.w_vo = (Rotation.from_matrix(np.array([results[k].R_c1c2 for k in ks])).as_rotvec()
                     if len(ks) else np.zeros((0, 3)))

    def residuals(self, shift: float, idx=None, w_vo=None) -> tuple[np.ndarray, np.ndarray]:
        """(VO minus bias-corrected gyro rotation vectors in camera axes, gyro rates (rad/s)),
        over the pairs `idx` (default all); `w_vo`: other VO rotation vectors for all pairs."""
        idx = slice(None) if idx is None else idx
        ta, tb, dt = self.ta[idx], self.tb[idx], self.dt[idx]
        w_vo = (self.w_vo if w_vo is None else w_vo)[idx]
        Rg, _ = self.gyro.between(ta + shift, tb + shift)
        Rc = np.einsum("ji,njk,kl->nil", self.R_bc, Rg, self.R_bc)  # R_bc^T Rg R_bc
        w_g = Rotation.from_matrix(Rc).as_rotvec()
        # the bias as a Huber M-estimate (IRLS from the median): a median alone jumps from pair
        # to pair as the shift moves and made the real clip's cost ragged
        x = (w_g - w_vo) / dt[:, None]
        b = np.median(x, axis=0)
        s = max(1.4826 * float(np.median(np.abs(x - b))), 1e-9)
        for _ in range(5):
            r = np.linalg.norm(x - b, axis=1) / s
            wt = np.minimum(1.0, HUBER_C / np.maximum(r, 1e-12))
            b = (wt[:, None] * x).sum(axis=0) / wt.sum()
        b = np.clip(b, -5 * GYRO_BIAS_STD, 5 * GYRO_BIAS_STD)
        return w_vo - (w_g - b * dt[:, None]), w_g / dt[:, None]


def _sigma(E: np.ndarray) -> float:
    return max(float(1.4826 * np.median(np.abs(E - np.median(E, axis=0)))), 1e-7)


def _huber_nll(E: np.ndarray, sigma: float) -> float:
    r = np.abs(E) / sigma
    return float(0.5 * np.sum(np.where(r <= HUBER_C, r * r, 2 * HUBER_C * r - HUBER_C**2)))


def _rms_deg(E: np.ndarray) -> float:
    return float(np.degrees(np.sqrt(np.mean(np.sum(E * E, axis=1))))) if len(E) else float("nan")


def estimate_time_offset(results: list, gyro: GyroIntegrator, t_cam, R_bc: np.ndarray, calib_s: float,
                         search_s: float = SEARCH_S, flags: list | None = None,
                         stabilised: bool = False) -> TimeOffset:
    """The shift (t_imu = t_cam + shift) that best aligns VO's per-pair rotations with the gyro.

    results: VoResult (or None) per frame, entry k the pair (k-1, k); t_cam: frame stamps on
    the camera clock; flags: the trust check's per-frame flags (flagged pairs are left out)."""
    out = TimeOffset(shift_s=calib_s, calib_s=calib_s, method="calib.yaml (estimate undetermined)")
    if stabilised:
        out.reason = "the video is stabilised (the image does not turn with the body)"
        return out
    lo, hi = calib_s - search_s, calib_s + search_s
    P = _Pairs(results, gyro, t_cam, R_bc, flags, lo, hi)
    out.pairs = len(P.k)
    if out.pairs < MIN_PAIRS:
        out.reason = f"{out.pairs} usable VO pairs with a rotation (at least {MIN_PAIRS} needed)"
        return out
    E0, rates = P.residuals(calib_s)
    out.residual_calib_deg = out.residual_used_deg = _rms_deg(E0)
    # consecutive pairs only: the change of rate the offset is seen through
    cons = np.flatnonzero(np.diff(P.k) == 1)
    out.rate_change_dps = float(np.degrees(np.sqrt(np.mean(np.sum((rates[cons + 1] - rates[cons]) ** 2, axis=1))))
                                if len(cons) else 0.0)
    frame_dt = float(np.median(P.dt))
    step = float(np.clip(frame_dt / 4.0, 0.002, search_s / 2.0))
    # one noise scale for every candidate (else the cost is not comparable between them): the
    # smallest robust spread over the coarse grid, i.e. at the best-aligned candidate
    grid = np.linspace(lo, hi, max(int(np.ceil(2 * search_s / step - 1e-9)), 2) + 1)
    sigma = min(_sigma(P.residuals(float(s))[0]) for s in grid)
    coarse, fine, f_span, out.profile, out.std_jackknife_s = profile_jackknife(
        lambda s, idx: _huber_nll(P.residuals(s, idx)[0], sigma), lo, hi, step, out.pairs)
    out.estimate_s = fine.tau_s
    out.std_curvature_s = fine.std_s if np.isfinite(fine.std_s) else None
    out.std_s = None if out.std_curvature_s is None else max(out.std_curvature_s, out.std_jackknife_s)
    if coarse.at_limit:
        out.reason = f"the cost is lowest at the end of the search range (calib +- {search_s * 1e3:.0f} ms)"
    elif out.std_s is None:
        out.reason = (f"the cost is flat: too little change of rotation between frames "
                      f"({out.rate_change_dps:.1f} deg/s RMS)")
    elif out.std_s > MAX_STD_S:
        head = (f"1-sigma {out.std_s * 1e3:.1f} ms > {MAX_STD_S * 1e3:.0f} ms (curvature "
                f"{out.std_curvature_s * 1e3:.1f}, jackknife {out.std_jackknife_s * 1e3:.1f}): ")
        if out.std_jackknife_s > 3 * out.std_curvature_s:
            out.reason = head + (f"parts of the recording disagree (VO and gyro rotations differ beyond noise: "
                                 f"lens model, rolling shutter, moving objects?) with little change of rotation "
                                 f"between frames ({out.rate_change_dps:.1f} deg/s RMS)")
        else:
            out.reason = head + (f"too little change of rotation between frames ({out.rate_change_dps:.1f} deg/s RMS) "
                                 f"for the VO noise")
    else:
        out.shift_s, out.method = fine.tau_s, "estimated"
        out.reason = (f"VO-gyro rotation profile over calib +- {search_s * 1e3:.0f} ms "
                      f"(step {step * 1e3:.1f} ms, then {f_span / 8 * 1e3:.1f} ms, parabola; 1-sigma: curvature "
                      f"{out.std_curvature_s * 1e3:.2f} ms, jackknife over {JACKKNIFE_BLOCKS} blocks "
                      f"{out.std_jackknife_s * 1e3:.2f} ms)")
        out.residual_used_deg = _rms_deg(P.residuals(out.shift_s)[0])
    return out


def profile_jackknife(cost, lo: float, hi: float, step: float, n_pairs: int):
    """Minimise cost(x, idx), a negative log-likelihood over the pairs idx (None: all), over
    [lo, hi]: a grid of `step`, then one of an eighth of the span about its best point, each with
    its parabola (`latency.profile_latency`). The curvature's 1-sigma assumes independent pairs
    and a right model; real residuals are neither (GoPro Karma: halves of the clip gave -74 +-
    0.6 and +12 +- 1.3 ms), so also the delete-one-block jackknife over JACKKNIFE_BLOCKS
    contiguous blocks of pairs. Returns (coarse, fine, the fine grid's span, the profile as
    sorted (x, cost above its minimum), the jackknife's 1-sigma)."""
    memo: dict = {}

    def minimise(idx=None, memo=None):
        def c(x: float) -> float:
            x = round(float(x), 9)
            if memo is None:
                return cost(x, idx)
            if x not in memo:
                memo[x] = cost(x, idx)
            return memo[x]

        coarse = profile_latency(c, lo, hi, step=step)
        # finer about the coarse minimum: the residuals are linear in x only for small errors
        f_lo, f_hi = max(lo, coarse.tau_s - step), min(hi, coarse.tau_s + step)
        return coarse, profile_latency(c, f_lo, f_hi, step=(f_hi - f_lo) / 8.0), f_hi - f_lo

    coarse, fine, f_span = minimise(None, memo)
    m = min(memo.values())
    blocks = np.array_split(np.arange(n_pairs), JACKKNIFE_BLOCKS)
    th = np.array([minimise(np.setdiff1d(np.arange(n_pairs), b))[1].tau_s for b in blocks])
    std_jack = float(np.sqrt((len(th) - 1) / len(th) * np.sum((th - th.mean()) ** 2)))
    return coarse, fine, f_span, sorted((x, c - m) for x, c in memo.items()), std_jack


def not_estimated(calib_s: float, why: str) -> TimeOffset:
    return TimeOffset(shift_s=calib_s, calib_s=calib_s, method="calib.yaml (estimate undetermined)", reason=why)
