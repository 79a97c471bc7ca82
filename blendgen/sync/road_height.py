"""Road-height constraint: a road vehicle stays on the road surface, so the height of a point
fixed to it (the camera, the GNSS antenna) is the twin's road height under it plus a constant
of the mount. Applied as an EKF pseudo-measurement every `EVERY_S`, so the estimated height
no longer follows the vertical GNSS noise (1.5-2x the horizontal, slow wander on real
receivers).

The road height is the twin's surface `z_road(x, y)` (`Twin.ground_heights`, with a map's
elevation and superelevation; its slope enters the Jacobian, so a horizontal error on a grade
is not a height error). The constrained point and its height above the road:
- the **camera**, when calib.yaml gives `vehicle.camera_height_m` (camera centre above the
  road): the fixes' heights stay in the filter as independent evidence;
- else the **antenna**, its height above the road estimated once from all fixes (trimmed mean
  of fix height minus road height, its error counted once per correlation time of the fixes).
  That height *is* the fixes' vertical information, so their per-fix heights are then left out
  of the filter (no double count), and its error, common to the whole drive, is spread over
  all pseudo-measurements (variance x their number).

Noise: road roughness and suspension heave/pitch at the point (`ROUGH_STD`) plus that error.

Without a twin there is no road-height pseudo-measurement: the vehicle-frame constraints
(no vertical velocity, pipeline.NHC_UP_STD) are the smooth local ground, and the fixes'
heights enter with their measured correlation time. A smooth ground fitted to the fixes
(local quadratic in distance travelled, +-150 m) was tried and not kept: on the 60 s synthetic
drive its height error (0.25 m RMS) was no better than the filter's (0.22 m, both limited by
that drive's GNSS noise, whose mean alone is -0.13 m), and on comma2k19 it biased the pitch
(1.07 deg median instead of 0.29): the scatter about a local fit underestimates the
receiver's slow height wander.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

ROUGH_STD = 0.03  # m: road roughness + suspension heave/pitch at the camera or antenna
EVERY_S = 1.0  # s between pseudo-measurements (suspension motion decorrelates in ~1 s)
# gate in metres, not chi-square: in a hard start (stop-and-go, tilt from an accelerating car)
# the vertical channel can be overconfident, and a chi-square gate then rejected every road
# update for 27 s while the height ran 3 m off; a residual beyond this means another surface
# (bridge, multi-level junction, a twin that does not match) and is rejected
MAX_RESIDUAL_M = 2.0


@dataclass
class RoadHeight:
    """Where the constrained point should be: `target(xy) -> (z, std, dz/dxy)`."""

    surface: Callable  # (N, 2) -> (N,) road z in the world (twin) frame
    point: str  # "camera" or "antenna"
    height_m: float  # the point's height above the road
    height_std_m: float  # 1-sigma of height_m (0: calibrated)
    spread: float = 1.0  # pseudo-measurements that share height_m's error

    def target(self, xy: np.ndarray):
        xy = np.asarray(xy, dtype=float)[:2]
        e = 0.5  # m: finite-difference step of the surface slope
        pts = np.array([xy, xy + [e, 0.0], xy - [e, 0.0], xy + [0.0, e], xy - [0.0, e]])
        z = np.asarray(self.surface(pts), dtype=float).reshape(-1)
        if z.shape != (5,) or not np.all(np.isfinite(z)):
            return None
        grad = np.array([z[1] - z[2], z[3] - z[4]]) / (2 * e)
        std = float(np.hypot(ROUGH_STD, self.height_std_m * np.sqrt(self.spread)))
        return float(z[0] + self.height_m), std, grad

    @property
    def replaces_fix_heights(self) -> bool:
        return self.point == "antenna"

    def summary(self) -> dict:
        return {"point": self.point, "height_m": round(self.height_m, 3),
                "height_std_m": round(self.height_std_m, 3), "every_s": EVERY_S, "std_m": ROUGH_STD}


def build(gt_t: np.ndarray, g_xyz: np.ndarray, corr_s: float, surface: Callable | None,
          camera_height_m: float | None = None) -> RoadHeight | None:
    """The road-height model of one recording: None without a twin surface, or without a
    known camera height and too few fixes to estimate the antenna's height."""
    if surface is None:
        return None
    if camera_height_m is not None:
        return RoadHeight(surface, "camera", float(camera_height_m), 0.0)
    if len(gt_t) < 10:
        return None
    d = g_xyz[:, 2] - np.asarray(surface(g_xyz[:, :2]), dtype=float).reshape(-1)
    d = d[np.isfinite(d)]
    if len(d) < 10:
        return None
    # mean of the fixes within 3 sigma of the median: as efficient as the mean for Gaussian
    # receiver noise (the median wastes a third of it), robust to outliers
    med = float(np.median(d))
    sig = max(1.4826 * float(np.median(np.abs(d - med))), 1e-3)
    d = d[np.abs(d - med) <= 3 * sig]
    rate = 1.0 / max(float(np.median(np.diff(gt_t))), 1e-3)
    n_eff = max(len(d) / max(corr_s * rate, 1.0), 1.0)
    h_std = float(d.std()) / np.sqrt(n_eff)
    span = float(gt_t[-1] - gt_t[0])
    return RoadHeight(surface, "antenna", float(d.mean()), h_std, spread=max(span / EVERY_S, 1.0))


def apply(ekf, road: RoadHeight, p_bc: np.ndarray) -> bool:
    """One pseudo-measurement at the filter's current state (camera or antenna point)."""
    cam = road.point == "camera"
    q = ekf.p + ekf.R @ (p_bc if cam else ekf.lever)
    tgt = road.target(q[:2])
    if tgt is None:
        return False
    z, std, grad = tgt
    return ekf.update_height(z, std, p_bc if cam else None, grad, max_residual=MAX_RESIDUAL_M)
