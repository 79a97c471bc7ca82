"""How much to trust visual odometry: per-pair measurement noise, and checks of each pair
against the gyro.

Noise (`vo_noise`): the first-order covariance of each pair's own fit (`VoResult.rot_cov`,
`dir_cov`: the Sampson residuals' Jacobian and mean square over the RANSAC inliers, or the
linearised Kabsch fit for rotation-only and stationary pairs), so it grows with fewer inliers,
larger residuals, less parallax and a shorter baseline; inflated by the factor the first-order
model underestimates the true error on the synthetic drive (measured: 2.2-3.5x in std, see
docs/sync.md), with floors for what no pixel residual shows (rolling shutter, time offset).
"""

from __future__ import annotations

import numpy as np

from blendgen.sync.vo import VoResult

# measured on the 60 s synthetic drive (480x270, 5 fps; ORB and KLT): true / predicted std
# was 2.1-2.4 for the rotation and 2.6-3.2 for the direction (median NEES per dof 2.2-7.5)
VO_ROT_INFLATE = 2.5
VO_DIR_INFLATE = 3.5
# floors: what no pixel residual shows. Per pair the rotation has a mean error of ~0.01 deg per
# axis (synthetic drive, ORB and KLT alike): trusted more tightly it is read as a gyro bias of
# ~8e-4 rad/s and tilts the camera (60 s drive: 0.09 -> 0.16 deg with floors of 0.01 / 0.1 deg)
VO_ROT_FLOOR = np.radians(0.08)
VO_DIR_FLOOR = np.radians(0.5)
VO_ROT_NO_COV = 0.003             # rad: a pair without a fit covariance (should not happen)


def vo_noise(res: VoResult) -> tuple[np.ndarray, np.ndarray | None]:
    """(3x3 rotation covariance, 3x3 direction covariance or None) for a VO pair."""
    if res.rot_cov is not None:
        rot = VO_ROT_INFLATE**2 * res.rot_cov + VO_ROT_FLOOR**2 * np.eye(3)
    else:
        rot = VO_ROT_NO_COV**2 * np.eye(3)
    if not res.has_direction or res.u_dir is None:
        return rot, None
    u = np.asarray(res.u_dir, dtype=float)
    tangent = np.eye(3) - np.outer(u, u)
    dcov = res.dir_cov if res.dir_cov is not None else np.radians(0.7) ** 2 * tangent
    return rot, VO_DIR_INFLATE**2 * dcov + VO_DIR_FLOOR**2 * tangent
