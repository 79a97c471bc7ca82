"""In-memory model of a recording folder (DESIGN.md "A recording").

Arrays, one row per sample, all times on one clock in seconds:
  frames_t    (N,)   frame timestamps
  imu         (M,7)  t, wx, wy, wz, ax, ay, az   (rad/s, m/s^2, IMU frame)
  gnss        (K,C)  t, lat, lon, alt[, heading_deg][, h_std_m]  -> see gnss_columns
  groundtruth (G,8)  t, x, y, z, qw, qx, qy, qz  (T_world_cam in the twin frame)
  speed       (S,2)  t, speed   (m/s: the vehicle's odometer / CAN wheel speed, forward, >= 0)
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from blendgen.geometry import Camera


@dataclass
class ImuNoise:
    """Continuous-time IMU noise in Kalibr's names and units."""

    accelerometer_noise_density: float = 2.0e-3  # m/s^2/sqrt(Hz)
    accelerometer_random_walk: float = 3.0e-3  # m/s^3/sqrt(Hz)
    gyroscope_noise_density: float = 1.7e-4  # rad/s/sqrt(Hz)
    gyroscope_random_walk: float = 2.0e-5  # rad/s^2/sqrt(Hz)
    update_rate: float = 200.0  # Hz
    # blendgen's priors on the turn-on biases (1 sigma; not Kalibr's): a calibrated automotive
    # MEMS unit; consumer cameras' datasheets allow +-40 mg (the GoPro importer writes 0.3 m/s^2)
    accelerometer_bias_std: float = 0.1  # m/s^2
    gyroscope_bias_std: float = 0.01  # rad/s


@dataclass
class Recording:
    root: Path
    camera: Camera | None
    T_cam_imu: np.ndarray = field(default_factory=lambda: np.eye(4))
    imu_noise: ImuNoise = field(default_factory=ImuNoise)
    time_offset_cam_imu: float = 0.0  # Kalibr timeshift_cam_imu: t_imu = t_cam + shift
    # calib.yaml `timeshift_cam_imu: auto` (or timeshift_cam_imu_estimate: true): sync estimates
    # it from VO vs gyro within time_offset_cam_imu +- time_offset_search_s (blendgen.sync.time_offset)
    time_offset_estimate: bool = False
    time_offset_search_s: float = 0.1
    rolling_shutter_s: float = 0.0  # camera readout, top row to bottom row; a frame's stamp is its top row
    rolling_shutter_estimate: bool = False  # calib `rolling_shutter_s: auto`: sync estimates it (sync.readout)
    frames_t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    frame_files: list[str] | None = None  # image files relative to root, or None with a video
    video: str | None = None  # video file relative to root (frames.csv then holds t, index)
    frame_index: np.ndarray | None = None  # video frame index per row of frames.csv
    imu: np.ndarray = field(default_factory=lambda: np.zeros((0, 7)))
    gnss: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    gnss_columns: list[str] = field(default_factory=lambda: ["t", "lat", "lon", "alt"])
    groundtruth: np.ndarray | None = None
    speed: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    extra: dict = field(default_factory=dict)  # calib.yaml keys blendgen does not interpret
    issues: list[str] = field(default_factory=list)  # handled gaps reported by the reader

    @property
    def n_frames(self) -> int:
        return len(self.frames_t)

    def frame_id(self, i: int) -> str:
        return f"f{i:06d}"

    def utc(self, t: float):
        """Absolute UTC time of recording time t (for the sun's position), or None.

        calib.yaml may give `time_origin_utc` (ISO 8601) for clocks that start at 0;
        otherwise t > 1e9 is taken as Unix time.
        """
        from datetime import datetime, timedelta, timezone

        origin = self.extra.get("time_origin_utc")
        if origin:
            start = datetime.fromisoformat(str(origin).replace("Z", "+00:00"))
            return start + timedelta(seconds=float(t))
        if t > 1e9:
            return datetime.fromtimestamp(float(t), tz=timezone.utc)
        return None

    @property
    def lens_source(self) -> str:
        """Where the intrinsics come from: "assumed" (the importer guessed a field of view),
        "profile" (a lens database's calibration of the camera model, not of this unit: e.g.
        `import gopro --lens`) or "calibrated" (anything else: this camera's calibration)."""
        cal = str((self.extra.get("import") or {}).get("camera_calibration", ""))
        return "assumed" if cal.startswith("assumed") else "profile" if "lens profile" in cal else "calibrated"

    def gnss_col(self, name: str) -> np.ndarray | None:
        return self.gnss[:, self.gnss_columns.index(name)] if name in self.gnss_columns else None
