"""Frames, poses and the pinhole camera shared by all stages (conventions in DESIGN.md).

World: right-handed, z up (ENU when georeferenced). Camera: OpenCV (x right, y down,
z forward). A pose is T_world_cam, a 4x4 matrix mapping camera to world coordinates.
Quaternions are Hamilton (qw, qx, qy, qz).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

# Blender cameras look down -z with y up; OpenCV cameras look down +z with y down.
CV_TO_BLENDER = np.diag([1.0, -1.0, -1.0])


def quat_to_matrix(q_wxyz) -> np.ndarray:
    q = np.asarray(q_wxyz, dtype=float)
    return Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()


def matrix_to_quat(R) -> np.ndarray:
    """Rotation matrix -> Hamilton (qw, qx, qy, qz) with qw >= 0."""
    x, y, z, w = Rotation.from_matrix(np.asarray(R, dtype=float)).as_quat()
    q = np.array([w, x, y, z])
    return -q if q[0] < 0 else q


def make_pose(R, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.ravel(t)
    return T


def invert_pose(T) -> np.ndarray:
    R, t = T[:3, :3], T[:3, 3]
    return make_pose(R.T, -R.T @ t)


def pose_from_xyz_quat(xyz, q_wxyz) -> np.ndarray:
    return make_pose(quat_to_matrix(q_wxyz), xyz)


def pose_to_xyz_quat(T) -> tuple[np.ndarray, np.ndarray]:
    return np.asarray(T[:3, 3], dtype=float).copy(), matrix_to_quat(T[:3, :3])


def R_world_cam_from_ypr(yaw: float, pitch: float = 0.0, roll: float = 0.0) -> np.ndarray:
    """Camera orientation for a vehicle heading `yaw` (rad, from world +x toward +y).

    pitch > 0 tilts the optical axis up, roll > 0 rolls clockwise as seen by the camera.
    With zero angles the optical axis (cam z) points along world (cos yaw, sin yaw, 0),
    cam x points to the right of the heading, and cam y points down (world -z).
    """
    # Body frame: x forward, y left, z up. Camera axes in the body frame:
    R_body_cam = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    R_world_body = Rotation.from_euler("ZYX", [yaw, -pitch, roll]).as_matrix()
    return R_world_body @ R_body_cam


def yaw_of_camera(R_world_cam) -> float:
    """Heading (rad) of the optical axis projected on the ground plane."""
    z = np.asarray(R_world_cam)[:, 2]
    return float(np.arctan2(z[1], z[0]))


def cv_to_blender_rotation(R_world_cam_cv) -> np.ndarray:
    return np.asarray(R_world_cam_cv) @ CV_TO_BLENDER


@dataclass
class Camera:
    """Pinhole camera with optional radial-tangential distortion (OpenCV k1 k2 p1 p2 k3)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    dist: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0, 0.0, 0.0])

    @classmethod
    def from_hfov(cls, width: int, height: int, hfov_deg: float) -> "Camera":
        f = 0.5 * width / np.tan(np.radians(hfov_deg) / 2)
        return cls(width, height, f, f, (width - 1) / 2, (height - 1) / 2)

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])

    @property
    def D(self) -> np.ndarray:
        return np.asarray(self.dist, dtype=float)

    @property
    def distorted(self) -> bool:
        return bool(np.any(np.abs(self.D) > 0))

    def scaled(self, width: int, height: int) -> "Camera":
        """The same camera at another resolution (pixel centres at integers)."""
        sx, sy = width / self.width, height / self.height
        return Camera(width, height, self.fx * sx, self.fy * sy,
                      (self.cx + 0.5) * sx - 0.5, (self.cy + 0.5) * sy - 0.5, list(self.dist))

    def project(self, X_cam) -> tuple[np.ndarray, np.ndarray]:
        """Project Nx3 camera-frame points. Returns (uv Nx2, in_front N bool)."""
        X = np.atleast_2d(np.asarray(X_cam, dtype=float))
        in_front = X[:, 2] > 1e-6
        z = np.where(in_front, X[:, 2], 1.0)
        if self.distorted:
            import cv2

            uv, _ = cv2.projectPoints(X.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), self.K, self.D)
            uv = uv.reshape(-1, 2)
        else:
            uv = np.stack([self.fx * X[:, 0] / z + self.cx, self.fy * X[:, 1] / z + self.cy], axis=1)
        return uv, in_front

    def project_world(self, T_world_cam, X_world) -> tuple[np.ndarray, np.ndarray]:
        T_cam_world = invert_pose(np.asarray(T_world_cam))
        X = np.atleast_2d(np.asarray(X_world, dtype=float))
        Xc = X @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
        return self.project(Xc)

    def to_dict(self) -> dict:
        return asdict(self)
