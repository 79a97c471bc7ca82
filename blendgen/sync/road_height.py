"""Road-height constraint: a road vehicle stays on the road surface, so the height of a point
fixed to it (the camera, the GNSS antenna) is the road's height under it plus a constant of
the mount. Applied as an EKF pseudo-measurement instead of the fixes' heights, so the
estimated height no longer follows the vertical GNSS noise (1.5-2x the horizontal, and slow
wander on real receivers).

Two sources of the road height:
- **twin**: the twin's road surface `z_road(x, y)` (`Twin.ground_heights`, with a map's
  elevation). The point's height above it is calib.yaml `vehicle.camera_height_m` (camera
  centre above the road) when given, else the antenna's height above the road estimated once
  from all fixes (robust median, its error counted once per correlation time of the fixes).
- **smooth local ground** (no twin): a local quadratic fit of the fixes' heights against the
  distance travelled over +-`PROFILE_HALF_M` (at least +-`PROFILE_MIN_S` of fixes): roads
  change grade slowly, so the fit keeps hills and averages hundreds of fixes. Its error is
  estimated from the measured scatter about the fit and the fixes' correlation time.

The noise is honest: road roughness and suspension travel (`ROUGH_STD`) plus the source's own
error; errors common to a whole window are spread over the pseudo-measurements applied within
it (variance x their number), so the constraint carries no more information than its fixes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

ROUGH_STD = 0.03  # m: road roughness + suspension heave/pitch at the camera or antenna
EVERY_S = 1.0  # s between pseudo-measurements (suspension motion decorrelates in ~1 s)
PROFILE_HALF_M = 150.0  # m: half-width of the smooth-ground fit (vertical curves R >~ 1 km)
PROFILE_MIN_S = 10.0  # s: ... but at least this many seconds of fixes on each side


@dataclass
class RoadHeight:
    """Where the constrained point should be: `target(t, xy) -> (z, std, dz/dxy)`."""

    source: str  # "twin" or "profile"
    point: str  # "camera" or "antenna"
    height_m: float  # the point's height above the road (profile: 0, the fit is of the antenna)
    height_std_m: float
    surface: Callable | None = None  # twin: (N, 2) -> (N,) road z
    prof_t: np.ndarray | None = None  # profile: fix times, fitted height, its 1-sigma
    prof_z: np.ndarray | None = None
    prof_std: np.ndarray | None = None
    corr_blocks: float = 1.0  # pseudo-measurements per independent error of the source

    def target(self, t: float, xy: np.ndarray):
        if self.surface is not None:
            xy = np.asarray(xy, dtype=float)[:2]
            e = 0.5
            pts = np.array([xy, xy + [e, 0.0], xy - [e, 0.0], xy + [0.0, e], xy - [0.0, e]])
            z = np.asarray(self.surface(pts), dtype=float)
            if not np.all(np.isfinite(z)):
                return None
            grad = np.array([z[1] - z[2], z[3] - z[4]]) / (2 * e)
            std = np.hypot(ROUGH_STD, self.height_std_m * np.sqrt(self.corr_blocks))
            return float(z[0] + self.height_m), float(std), grad
        z = float(np.interp(t, self.prof_t, self.prof_z))
        s = float(np.interp(t, self.prof_t, self.prof_std))
        return z, float(np.hypot(ROUGH_STD, s * np.sqrt(self.corr_blocks))), np.zeros(2)

    def summary(self) -> dict:
        out = {"source": self.source, "point": self.point, "every_s": EVERY_S}
        if self.source == "twin":
            out.update(height_m=round(self.height_m, 3), height_std_m=round(self.height_std_m, 3))
        else:
            out.update(profile_std_m=round(float(np.median(self.prof_std)), 3))
        return out


def _distance_travelled(t: np.ndarray, xy: np.ndarray, half_s: float = 2.0) -> np.ndarray:
    """Distance along the fixes from a local linear speed fit (+-half_s): summing fix-to-fix
    steps would add the fixes' noise (1 m at 10 Hz: 14 m/s of fake speed while parked)."""
    n = len(t)
    speed = np.zeros(n)
    lo = np.searchsorted(t, t - half_s)
    hi = np.searchsorted(t, t + half_s, side="right")
    for i in range(n):
        tt = t[lo[i]:hi[i]]
        if len(tt) < 3:
            continue
        A = np.column_stack([np.ones_like(tt), tt - t[i]])
        coef, *_ = np.linalg.lstsq(A, xy[lo[i]:hi[i]], rcond=None)
        speed[i] = np.linalg.norm(coef[1])
    return np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(t))])


def ground_profile(t: np.ndarray, xyz: np.ndarray, corr_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Smooth local ground from the fixes: per fix, a tricube-weighted quadratic fit of the
    heights against the distance travelled; returns (height, its 1-sigma). The sigma uses the
    measured scatter about the fits (robust) and counts one independent fix per `corr_s`."""
    n = len(t)
    s = _distance_travelled(t, xyz[:, :2])
    z = xyz[:, 2]
    rate = 1.0 / max(float(np.median(np.diff(t))), 1e-3)
    per = max(corr_s * rate, 1.0)  # fixes per independent height error
    out = np.zeros(n)
    var_fac = np.zeros(n)  # sum(l^2): variance of the fit per unit fix variance
    for i in range(n):
        lo_t, hi_t = np.searchsorted(t, [t[i] - PROFILE_MIN_S, t[i] + PROFILE_MIN_S])
        half = max(PROFILE_HALF_M, s[i] - s[max(lo_t, 0)], s[min(hi_t, n - 1)] - s[i], 1e-3)
        j0, j1 = np.searchsorted(s, [s[i] - half, s[i] + half])
        j1 = max(j1, j0 + 1)
        u = (s[j0:j1] - s[i]) / half
        w = np.clip(1 - np.abs(u) ** 3, 0, None) ** 3 + 1e-6
        deg = 2 if j1 - j0 >= 20 and np.ptp(u) > 0.5 else 0
        A = np.vander(u, deg + 1, increasing=True)
        Aw = A * w[:, None]
        # the fit at u = 0 is l @ z with l = e0^T (A^T W A)^-1 A^T W
        l = np.linalg.lstsq(Aw.T @ A, Aw.T, rcond=None)[0][0]
        out[i] = l @ z[j0:j1]
        var_fac[i] = l @ l
    r = z - out
    scatter = 1.4826 * float(np.median(np.abs(r - np.median(r))))
    # correlated fixes: per independent error `per` fixes carry one fix's information
    std = scatter * np.sqrt(var_fac * per)
    return out, np.maximum(std, 1e-3)


def build(gt_t: np.ndarray, g_xyz: np.ndarray, corr_s: float, surface: Callable | None = None,
          camera_height_m: float | None = None) -> RoadHeight | None:
    """The road-height model of one recording (None with too few fixes and no known height)."""
    rate = 1.0 / max(float(np.median(np.diff(gt_t))), 1e-3) if len(gt_t) > 1 else 1.0
    if surface is not None:
        if camera_height_m is not None:
            return RoadHeight("twin", "camera", float(camera_height_m), 0.0, surface=surface)
        if len(gt_t) < 10:
            return None
        d = g_xyz[:, 2] - np.asarray(surface(g_xyz[:, :2]), dtype=float)
        d = d[np.isfinite(d)]
        if len(d) < 10:
            return None
        # mean of the fixes within 3 sigma of the median: as efficient as the mean for the
        # receiver's Gaussian noise (the median wastes 1 - 2/pi of it), robust to outliers
        med = float(np.median(d))
        sig = max(1.4826 * float(np.median(np.abs(d - med))), 1e-3)
        d = d[np.abs(d - med) <= 3 * sig]
        h = float(d.mean())
        n_eff = max(len(d) / max(corr_s * rate, 1.0), 1.0)
        h_std = float(d.std()) / np.sqrt(n_eff)
        span = float(gt_t[-1] - gt_t[0])
        # one error for the whole drive, spread over all its pseudo-measurements
        return RoadHeight("twin", "antenna", h, h_std, surface=surface, corr_blocks=max(span / EVERY_S, 1.0))
    if len(gt_t) < 30:
        return None
    z, std = ground_profile(gt_t, g_xyz, corr_s)
    # the profile's error is common to the fixes of a window (PROFILE_MIN_S each side at least)
    return RoadHeight("profile", "antenna", 0.0, 0.0, prof_t=gt_t, prof_z=z, prof_std=std,
                      corr_blocks=max(2 * PROFILE_MIN_S / EVERY_S, 1.0))


def apply(ekf, road: RoadHeight, t: float, p_bc: np.ndarray) -> bool:
    """One pseudo-measurement at the filter's current state (camera or antenna point)."""
    la = p_bc if road.point == "camera" else ekf.lever
    q = ekf.p + ekf.R @ la
    tgt = road.target(t, q[:2])
    if tgt is None:
        return False
    z, std, grad = tgt
    return ekf.update_height(z, std, p_bc if road.point == "camera" else None, grad)
