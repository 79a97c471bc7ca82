"""Rolling-shutter readout time from the data (calib.yaml `camera.rolling_shutter_s: auto`).

Row v of a frame is read `readout (v + 0.5) / H` after its stamp; while it is read the camera
turns, and VO solved on the uncorrected bearings returns a rotation the gyro does not (on a
shaking drive at 10 fps and 30 ms: the per-pair VO/gyro gain about the optical axis 0.95). For
a candidate readout each pair's bearings are turned back with the gyro (`vo.rs_bearings`, the
same correction the sync then applies) and its rotation refitted from the pair's own inliers
(Sampson refit of the essential matrix from the pair's solution, or Kabsch for rotation-only
pairs: no new RANSAC, so the set of points stays the same for every candidate). The cost is
the time-offset estimator's (`time_offset`: Huber negative log-likelihood of the VO-minus-gyro
rotation vectors, gyro bias refitted per candidate, one noise scale), minimised over [0,
max] by the same profile and jackknife.

The readout is seen through the camera's rotation *during* a frame, so it needs rotation (shake,
turns); a smooth drive or a drone's slow pans leave the cost flat and the readout is then not
used. The readout trades against the camera-IMU time offset (a readout r looks much like a
shift of r / 2; on the synthetic drive the joint cost's valley runs from (0 ms, +5 ms) to (40
ms, -5 ms), its minimum at the truth): with the offset unknown too, each candidate's cost is
minimised over the shift (`shift_search_s`), and the caller rebuilds the gyro tables at the
shift found and estimates again (`pipeline._estimate_readout`; docs/sync.md, "Rolling shutter").
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import minimize_scalar
from scipy.spatial.transform import Rotation

from blendgen import so3
from blendgen.sync.latency import profile_latency
from blendgen.sync.time_offset import _huber_nll, _Pairs, _rms_deg, _sigma, profile_jackknife
from blendgen.vo import _kabsch, _refine_rt, rs_bearings

MAX_S = 0.05          # search [0, MAX_S], and below the frame interval
STEP_S = 0.005
MAX_STD_S = 0.005     # a 1-sigma above this: undetermined, the readout is not used
MIN_PAIRS = 20
MAX_PAIRS = 300       # pairs refitted per candidate (evenly over the recording)
GN_ITERS = 3          # refit steps per pair and candidate readout (vo._refine_rt)
GN_DAMPING = 1e-2     # Marquardt's: with little parallax the direction of travel is poorly fixed
                      # and an undamped step there drags the rotation (real drone clip: ragged)
LATTICE_S = STEP_S / 4  # refits on this lattice, linear between (the grids of 5 and 2.5 ms lie on it)
ZERO_BOUND_S = 0.01   # a minimum at 0 is an estimate when the cost is 2 higher (~95 %) by this readout


@dataclass
class Readout:
    """How the readout used by sync was found (`summary["rolling_shutter"]`)."""

    readout_s: float                    # used
    method: str                         # "estimated" or "not estimated"
    estimate_s: float | None = None
    std_s: float | None = None          # the larger of the curvature's and the jackknife's
    std_curvature_s: float | None = None
    std_jackknife_s: float | None = None
    pairs: int = 0
    reason: str = ""
    shift_s: float = 0.0                # with a shift search: the best shift of the frame times
    residual_zero_deg: float | None = None  # RMS VO-gyro rotation difference per pair without correction
    residual_used_deg: float | None = None  # ... at the readout used
    profile: list = field(default_factory=list)

    def summary(self) -> dict:
        r = lambda x, n: None if x is None else round(float(x), n)  # noqa: E731
        return {"readout_s": r(self.readout_s, 5), "method": self.method, "estimate_s": r(self.estimate_s, 5),
                "std_s": r(self.std_s, 5), "std_curvature_s": r(self.std_curvature_s, 5),
                "std_jackknife_s": r(self.std_jackknife_s, 5), "pairs": self.pairs, "reason": self.reason,
                "shift_s": r(self.shift_s, 5),
                "residual_zero_deg": r(self.residual_zero_deg, 4), "residual_used_deg": r(self.residual_used_deg, 4),
                "profile": [[round(a, 5), round(b, 3)] for a, b in self.profile]}


def describe(s: dict) -> str:
    """One line for the command."""
    ro = s["readout_s"] * 1e3
    if s["method"] == "estimated" and ro == 0:
        return f"rolling shutter: readout 0 estimated from {s['pairs']} VO-gyro rotation pairs ({s['reason']})"
    if s["method"] == "estimated":
        out = (f"rolling shutter: readout {ro:.1f} +- {s['std_s'] * 1e3:.1f} ms estimated from {s['pairs']} "
               f"VO-gyro rotation pairs")
        if s.get("residual_zero_deg") is not None:
            out += f"; VO-gyro rotation residual {s['residual_zero_deg']:.3f} -> {s['residual_used_deg']:.3f} deg RMS"
        return out
    return f"rolling shutter: not corrected (readout not estimated: {s['reason']})"


def refit_rotation(res, spin1, spin2, readout_s: float, height: int) -> np.ndarray:
    """R_c1c2 of a VO pair refitted from its kept inliers (`VoResult.matches`, uncorrected
    bearings) after turning each frame's rows back by its readout turn table (`rs_bearings`)."""
    p1, p2, q1, q2 = res.matches
    b1 = rs_bearings(np.asarray(q1, float), p1, spin1, readout_s, height)
    b2 = rs_bearings(np.asarray(q2, float), p2, spin2, readout_s, height)
    if res.status == "ok":
        R21 = res.R_c1c2.T
        # a few damped steps from the uncorrected solution (the small change a readout makes)
        R21 = _refine_rt(R21, -R21 @ res.u_dir, b1[:, :2] / b1[:, 2:], b2[:, :2] / b2[:, 2:],
                         max_iter=GN_ITERS, damping=GN_DAMPING)[0]
    else:
        R21 = so3.orthonormalize(_kabsch(b1 / np.linalg.norm(b1, axis=1, keepdims=True),
                                         b2 / np.linalg.norm(b2, axis=1, keepdims=True)))
    return R21.T


def estimate_readout(results: list, gyro, t_imu, R_bc: np.ndarray, spins_at, height: int,
                     max_s: float = MAX_S, shift_search_s: float = 0.0) -> Readout:
    """The readout that best aligns VO's per-pair rotations with the gyro.

    results: VoResult (or None) per frame, entry k the pair (k-1, k), solved without correction
    and with `matches` kept; t_imu: frame stamps on the IMU clock; spins_at(readout): the
    per-frame turn tables (`pipeline._rs_spins`); height: image rows. shift_search_s > 0: the
    camera-IMU time offset is unknown too: each candidate's cost is minimised over a shift of
    t_imu within +- shift_search_s (the gyro tables stay those of t_imu: `Readout.shift_s` says
    where to build them again)."""
    out = Readout(readout_s=0.0, method="not estimated")
    t_imu = np.asarray(t_imu, float)
    if len(t_imu) > 1:
        max_s = min(max_s, 0.95 * float(np.median(np.diff(t_imu))))
    usable = [k for k in range(1, len(results)) if results[k] is not None and results[k].matches is not None]
    keep = set(np.array(usable)[np.unique(np.linspace(0, len(usable) - 1, MAX_PAIRS).round().astype(int))]
               .tolist()) if usable else set()
    S = float(shift_search_s)
    P = _Pairs([r if k in keep else None for k, r in enumerate(results)], gyro, t_imu, R_bc, None, -S, S)
    out.pairs = len(P.k)
    if out.pairs < MIN_PAIRS:
        out.reason = f"{out.pairs} usable VO pairs with a rotation (at least {MIN_PAIRS} needed)"
        return out
    cache: dict = {}

    def refit(i: int) -> np.ndarray:
        if i not in cache:
            r = i * LATTICE_S
            tab = spins_at(r) if r > 0 else None
            R = [refit_rotation(results[k], tab[k - 1] if tab is not None else None,
                                tab[k] if tab is not None else None, r, height) for k in P.k]
            cache[i] = Rotation.from_matrix(np.array(R)).as_rotvec()
        return cache[i]

    def w_vo(r: float) -> np.ndarray:
        # the rotations move smoothly with the readout: between lattice points, linearly
        x = float(r) / LATTICE_S
        i = int(np.floor(x + 1e-9))
        a = x - i
        return refit(i) if a < 1e-6 else (1 - a) * refit(i) + a * refit(i + 1)

    step = min(STEP_S, max_s / 4)
    grid = np.linspace(0.0, max_s, max(int(np.ceil(max_s / step - 1e-9)), 2) + 1)
    d_step = min(float(np.median(P.dt)) / 4.0, S / 2.0) if S > 0 else 0.0
    d_grid = np.linspace(-S, S, max(int(np.ceil(2 * S / d_step - 1e-9)), 2) + 1) if S > 0 else [0.0]
    # one noise scale for every candidate, as in time_offset: the smallest spread over the grid
    sigma = min(_sigma(P.residuals(float(d), None, w_vo(r))[0]) for r in grid for d in d_grid)

    def best_shift(r: float, idx) -> tuple[float, float]:
        """(shift, cost) minimising the cost of readout r over the shift (0 without a search)."""
        if S <= 0:
            return 0.0, _huber_nll(P.residuals(0.0, idx, w_vo(r))[0], sigma)
        seen: dict = {}

        def at(d: float) -> float:
            seen[d] = _huber_nll(P.residuals(d, idx, w_vo(r))[0], sigma)
            return seen[d]

        # sharp in the shift (Huber: V-shaped away from its minimum): a grid, then Brent to 0.2 ms
        c = profile_latency(at, -S, S, step=d_step)
        minimize_scalar(at, bounds=(max(-S, c.tau_s - d_step), min(S, c.tau_s + d_step)), method="bounded",
                        options={"xatol": 2e-4})
        d = min(seen, key=seen.get)
        return d, seen[d]

    coarse, fine, f_span, out.profile, out.std_jackknife_s = profile_jackknife(
        lambda r, idx: best_shift(r, idx)[1], 0.0, max_s, step, out.pairs)
    out.shift_s = best_shift(fine.tau_s, None)[0]
    out.residual_zero_deg = _rms_deg(P.residuals(0.0, None, w_vo(0.0))[0])
    out.estimate_s = fine.tau_s
    out.std_curvature_s = fine.std_s if np.isfinite(fine.std_s) else None
    out.std_s = None if out.std_curvature_s is None else max(out.std_curvature_s, out.std_jackknife_s)
    if coarse.tau_s <= 1e-9:
        # a minimum at the search's start has no parabola about it: where the profile is 2
        # higher (a one-sided ~95 % bound) says whether "0" is seen or the cost is merely flat
        x, c = np.array(out.profile).T
        bound = float(np.interp(2.0, np.maximum.accumulate(c), x)) if c.max() >= 2.0 else np.inf
        if bound <= ZERO_BOUND_S and out.std_jackknife_s <= MAX_STD_S:
            out.method, out.estimate_s = "estimated", 0.0
            out.reason = (f"the cost is lowest without correction and 2 higher by {bound * 1e3:.1f} ms: a global "
                          f"shutter, or a readout too short to matter")
            out.residual_used_deg = out.residual_zero_deg
        elif bound > ZERO_BOUND_S:
            out.reason = (f"the cost is lowest without correction but rises slowly (2 higher only by "
                          f"{bound * 1e3:.0f} ms): too little rotation during the frames to see a readout")
        else:
            out.reason = (f"the cost is lowest without correction, but parts of the recording disagree "
                          f"(jackknife 1-sigma {out.std_jackknife_s * 1e3:.1f} ms > {MAX_STD_S * 1e3:.0f} ms)")
    elif coarse.at_limit:
        out.reason = f"the cost is lowest at the end of the search range ({max_s * 1e3:.0f} ms)"
    elif out.std_s is None:
        out.reason = "the cost is flat: too little rotation during the frames to see a readout"
    elif out.std_s > MAX_STD_S:
        out.reason = (f"1-sigma {out.std_s * 1e3:.1f} ms > {MAX_STD_S * 1e3:.0f} ms (curvature "
                      f"{out.std_curvature_s * 1e3:.1f}, jackknife {out.std_jackknife_s * 1e3:.1f})")
    else:
        out.readout_s, out.method = fine.tau_s, "estimated"
        out.reason = (f"VO-gyro rotation profile over 0-{max_s * 1e3:.0f} ms"
                      + (", the time offset profiled out" if S > 0 else "") + f" (step {step * 1e3:.1f} ms, then "
                      f"{f_span / 8 * 1e3:.2f} ms, parabola; 1-sigma: curvature {out.std_curvature_s * 1e3:.2f} ms, "
                      f"jackknife {out.std_jackknife_s * 1e3:.2f} ms)")
        out.residual_used_deg = _rms_deg(P.residuals(0.0, None, w_vo(out.readout_s))[0])
    return out
