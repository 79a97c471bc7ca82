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


# a pinhole canvas (rendering) and pinhole bearings (VO) hold rays up to here (tan = 11); a
# GoPro's Max lens modes reach past it
MAX_VIEW_ANGLE_DEG = 85.0


@dataclass
class Camera:
    """Pinhole camera with optional lens distortion: radial-tangential (`distortion_model`
    "radtan", OpenCV k1 k2 p1 p2 k3) or equidistant fisheye ("equidistant", Kannala-Brandt
    k1..k4 as OpenCV's cv2.fisheye and Kalibr: GoPro and other action-camera lenses)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    dist: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0, 0.0, 0.0])
    distortion_model: str = "radtan"

    @classmethod
    def from_hfov(cls, width: int, height: int, hfov_deg: float) -> "Camera":
        f = 0.5 * width / np.tan(np.radians(hfov_deg) / 2)
        return cls(width, height, f, f, (width - 1) / 2, (height - 1) / 2)

    @property
    def hfov_deg(self) -> float:
        """Horizontal field of view through the principal point, edge to edge of the image."""
        n = self.normalized([[-0.5, self.cy], [self.width - 0.5, self.cy]], iterations=40)
        return float(np.degrees(np.arctan(-n[0, 0]) + np.arctan(n[1, 0])))

    def max_view_angle_deg(self) -> float:
        """The largest angle off the optical axis over the image border, or inf where the lens
        model does not invert (a fisheye beyond its calibrated range). Rendering goes through a
        pinhole canvas and VO through pinhole bearings: both need every pixel below 90 deg."""
        u = np.linspace(-0.5, self.width - 0.5, 64)
        v = np.linspace(-0.5, self.height - 0.5, 36)
        px = np.concatenate([np.c_[u, np.full_like(u, v[0])], np.c_[u, np.full_like(u, v[-1])],
                             np.c_[np.full_like(v, u[0]), v], np.c_[np.full_like(v, u[-1]), v]])
        n = self.normalized(px, iterations=40)
        uv, _ = self.project(np.c_[n, np.ones(len(n))])
        if not np.all(np.isfinite(uv)) or np.abs(uv - px).max() > 0.01:
            return float("inf")
        return float(np.degrees(np.arctan(np.hypot(n[:, 0], n[:, 1]).max())))

    def too_wide(self) -> str | None:
        """Why blendgen cannot use this lens (a view past MAX_VIEW_ANGLE_DEG), or None."""
        a = self.max_view_angle_deg()
        if a <= MAX_VIEW_ANGLE_DEG:
            return None
        what = ("does not invert at the image border (beyond its calibrated range)" if np.isinf(a)
                else f"sees {a:.0f} deg off its axis at the image border")
        return (f"{what}; blendgen handles up to {MAX_VIEW_ANGLE_DEG:.0f} deg (it renders through a pinhole "
                "canvas and tracks pinhole bearings)")

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])

    @property
    def D(self) -> np.ndarray:
        return np.asarray(self.dist, dtype=float)

    @property
    def fisheye(self) -> bool:
        return self.distortion_model == "equidistant"

    @property
    def distorted(self) -> bool:
        # an equidistant lens is not a pinhole even with k = 0 (r = f theta)
        return self.fisheye or bool(np.any(np.abs(self.D) > 0))

    def scaled(self, width: int, height: int) -> "Camera":
        """The same camera at another resolution (pixel centres at integers)."""
        sx, sy = width / self.width, height / self.height
        return Camera(width, height, self.fx * sx, self.fy * sy,
                      (self.cx + 0.5) * sx - 0.5, (self.cy + 0.5) * sy - 0.5, list(self.dist),
                      self.distortion_model)

    def normalized(self, px, iterations: int = 0, P=None) -> np.ndarray:
        """Pixels (N, 2) -> undistorted normalised image coordinates (N, 2) (x/z, y/z), or
        undistorted pixels of the pinhole `P` (3x3): the inverse of `project`. `iterations` > 0
        iterates the radtan inverse to 1e-10 (OpenCV's default is 5 fixed steps); the fisheye
        inverse is exact (NaN for pixels past the lens model's range)."""
        import cv2

        px = np.asarray(px, dtype=np.float64).reshape(-1, 1, 2)
        if len(px) == 0:
            return np.zeros((0, 2))
        if self.distorted and not self.fisheye:
            if iterations:
                crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, iterations, 1e-10)
                return cv2.undistortPointsIter(px, self.K, self.D, None, P, crit).reshape(-1, 2)
            return cv2.undistortPoints(px, self.K, self.D, P=P).reshape(-1, 2)
        if self.fisheye:
            out = self._fisheye_normalized(px.reshape(-1, 2))
        else:
            out = (px.reshape(-1, 2) - [self.cx, self.cy]) / [self.fx, self.fy]
        if P is not None:
            out = cv2.perspectiveTransform(out[:, None, :], np.asarray(P, float)).reshape(-1, 2)
        return out

    def _fisheye_normalized(self, px: np.ndarray) -> np.ndarray:
        """The equidistant model's inverse: theta from theta_d = theta (1 + k1 theta^2 + ... +
        k4 theta^8) by a table over the polynomial's rising part and two Newton steps; NaN past
        it. (cv2.fisheye.undistortPoints starts Newton at theta = theta_d, which for a GoPro
        Linear profile's corners lands where the polynomial turns and fails.)"""
        k = self.D[:4]
        poly = np.polynomial.Polynomial([0.0, 1.0, 0.0, k[0], 0.0, k[1], 0.0, k[2], 0.0, k[3]])
        dpoly = poly.deriv()
        th = np.linspace(0.0, np.pi / 2, 4097)
        td = poly(th)
        rising = np.flatnonzero(np.diff(td) <= 0)
        end = rising[0] + 1 if len(rising) else len(th)
        xd = np.column_stack([(px[:, 0] - self.cx) / self.fx, (px[:, 1] - self.cy) / self.fy])
        rd = np.hypot(xd[:, 0], xd[:, 1])
        theta = np.interp(rd, td[:end], th[:end], right=np.nan)
        with np.errstate(divide="ignore", invalid="ignore"):
            for _ in range(2):  # the table is within 1e-6 rad: Newton, kept on the rising part
                theta = np.clip(theta - (poly(theta) - rd) / dpoly(theta), 0.0, th[end - 1])
        scale = np.where(rd > 1e-12, np.tan(theta) / np.maximum(rd, 1e-12), 1.0)
        return xd * np.where(theta < np.pi / 2, scale, np.nan)[:, None]

    def project(self, X_cam) -> tuple[np.ndarray, np.ndarray]:
        """Project Nx3 camera-frame points. Returns (uv Nx2, in_front N bool)."""
        X = np.atleast_2d(np.asarray(X_cam, dtype=float))
        in_front = X[:, 2] > 1e-6
        z = np.where(in_front, X[:, 2], 1.0)
        if self.distorted:
            import cv2

            proj = cv2.fisheye.projectPoints if self.fisheye else cv2.projectPoints
            uv, _ = proj(X.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), self.K, self.D)
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
