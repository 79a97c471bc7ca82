"""The vehicle's odometer (recording speed.csv: CAN wheel speed) for sync.

The filter takes a reading as the vehicle frame's forward velocity L seconds earlier over k
(`ErrorStateEkf.update_vehicle_speed`): the scale k (tyre radius; comma2k19's CAN speed reads
0.9 % low) and the latency L (the odometer's clock against the IMU's; comma2k19's CAN speed is
~0.04 s early against the ground truth) are calibration states. Readings come at ~100 Hz with
errors correlated over many of them (quantisation, wheel slip), so they enter as 0.1 s means,
each with the IMU's mean specific force over its interval (L enters as L x the forward
acceleration).
"""

from __future__ import annotations

import numpy as np

EVERY_S = 0.1
LATENCY_PRIOR_STD_S = 0.2  # `speed_latency_s: auto`: estimated about 0 with this std
SCALE_RANGE = (0.8, 1.25)


def initial_scale(odo: np.ndarray, track: np.ndarray | None) -> float:
    """Least-squares scale k of the odometer means (`means` rows) against a smoothed forward-speed
    track (t, v) of a pass without them, where both say the car moves (> 2 m/s); 1 without enough."""
    if track is None or len(odo) < 2 or len(track) < 2:
        return 1.0
    s = np.interp(track[:, 0], odo[:, 0], odo[:, 1], left=np.nan, right=np.nan)
    ok = np.isfinite(s) & (s > 2.0) & (track[:, 1] > 2.0)
    if ok.sum() < 20:
        return 1.0
    k = float(s[ok] @ track[ok, 1]) / float(s[ok] @ s[ok])
    return float(np.clip(k, *SCALE_RANGE))


def means(speed: np.ndarray, imu: np.ndarray, every_s: float = EVERY_S) -> np.ndarray:
    """(t, speed) rows of speed.csv -> one row (t, mean speed, fx, fy, fz) per `every_s` bin
    that has readings: t the bin's mean stamp, f the mean specific force of the IMU samples in
    the bin (body frame; the nearest sample when none falls inside)."""
    if len(speed) == 0 or len(imu) == 0:
        return np.zeros((0, 5))
    b = np.floor((speed[:, 0] - speed[0, 0]) / every_s).astype(np.int64)
    ub, start, n = np.unique(b, return_index=True, return_counts=True)
    t = np.add.reduceat(speed[:, 0], start) / n
    s = np.add.reduceat(speed[:, 1], start) / n
    lo = speed[0, 0] + ub * every_s
    i0 = np.searchsorted(imu[:, 0], lo)
    i1 = np.searchsorted(imu[:, 0], lo + every_s)
    cs = np.vstack([np.zeros(3), np.cumsum(imu[:, 4:7], axis=0)])
    near = np.clip(np.searchsorted(imu[:, 0], t), 0, len(imu) - 1)
    m = (i1 - i0)[:, None]
    f = np.where(m > 0, (cs[i1] - cs[i0]) / np.maximum(m, 1), imu[near, 4:7])
    return np.column_stack([t, s, f])
