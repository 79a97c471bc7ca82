"""Error-state EKF: IMU propagation on SO(3), position / zero-velocity / relative-pose updates.

Nominal state: position p, velocity v (world, z up), orientation R = R_world_body, gyro bias
bg, accelerometer bias ba. Error state (15): [dp, dv, dtheta, dbg, dba] with the rotation
error local to the body, R_true = R Exp(dtheta). Six more error entries hold a stochastic
clone of (p, theta) at the last camera frame, so visual odometry (relative rotation and
translation direction between two frames) enters as a proper relative measurement.

Every update uses the Joseph form, is chi-square gated and symmetrised; after a run of
rejections the measurement is re-accepted with inflated noise so a filter that drifted
during a dropout can recover instead of rejecting the truth forever.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2

from blendgen.sync import so3

GRAVITY = np.array([0.0, 0.0, -9.80665])
N = 21  # 15 error states + clone (dp_c, dtheta_c)
IP, IV, ITH, IBG, IBA, ICP, ICT = (slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12), slice(12, 15),
                                   slice(15, 18), slice(18, 21))


@dataclass
class EkfConfig:
    acc_noise: float = 2.0e-3     # m/s^2/sqrt(Hz)   (Kalibr accelerometer_noise_density)
    gyro_noise: float = 1.7e-4    # rad/s/sqrt(Hz)
    acc_walk: float = 3.0e-3      # m/s^3/sqrt(Hz)
    gyro_walk: float = 2.0e-5     # rad/s^2/sqrt(Hz)
    noise_inflation: float = 1.0  # >1 when calib.yaml gives raw datasheet densities (Kalibr advises inflating)
    max_imu_dt: float = 0.05      # a longer IMU interval is a gap: no integration across it
    gap_acc_std: float = 2.0      # m/s^2: how much the vehicle may accelerate unseen in a gap
    gap_gyro_std: float = 0.2     # rad/s: how much it may turn unseen in a gap
    acc_range: float = 156.0      # m/s^2 (16 g): a reading at or beyond it is saturated
    gyro_range: float = 34.0      # rad/s (~2000 deg/s)
    free_acc_std: float = 3.0     # without IMU: constant-velocity model, acceleration noise
    free_rot_std: float = 0.5     # without IMU: orientation random walk, rad/s/sqrt(Hz)
    chi2_prob: float = 0.9995
    max_rejects: int = 8          # re-accept after this many consecutive rejections


@dataclass
class EkfStats:
    imu_steps: int = 0
    imu_gaps: int = 0
    saturated: int = 0
    updates: dict = field(default_factory=dict)
    rejected: dict = field(default_factory=dict)

    def count(self, kind: str, accepted: bool) -> None:
        d = self.updates if accepted else self.rejected
        d[kind] = d.get(kind, 0) + 1


class ErrorStateEkf:
    def __init__(self, cfg: EkfConfig, t: float, p, v, R, P0_diag, *, use_imu: bool = True):
        self.cfg = cfg
        self.t = float(t)
        self.p = np.asarray(p, dtype=float).copy()
        self.v = np.asarray(v, dtype=float).copy()
        self.R = so3.orthonormalize(np.asarray(R, dtype=float))
        self.bg = np.zeros(3)
        self.ba = np.zeros(3)
        self.use_imu = use_imu
        self.yaw_only_motion = False  # without IMU and VO: roll/pitch stay as initialised
        self.P = np.eye(N) * 1e-6
        self.P[:15, :15] = np.diag(np.asarray(P0_diag, dtype=float))
        if not use_imu:  # biases are meaningless without an IMU: freeze them
            self.P[IBG, IBG] = np.eye(3) * 1e-12
            self.P[IBA, IBA] = np.eye(3) * 1e-12
        self.p_c = self.p.copy()
        self.R_c = self.R.copy()
        self.has_clone = False
        self.stats = EkfStats()
        self.history: list | None = None  # set to [] to record what the RTS smoother needs
        self._acc = None
        self._rejects: dict[str, int] = {}
        self._last_imu = None  # last valid (w, a) for saturated samples
        k = cfg.noise_inflation
        self._q_acc, self._q_gyro = (k * cfg.acc_noise) ** 2, (k * cfg.gyro_noise) ** 2
        self._q_ba, self._q_bg = (k * cfg.acc_walk) ** 2, (k * cfg.gyro_walk) ** 2

    # ------------------------------------------------------------------ propagation
    def propagate_imu(self, t: float, w_m, a_m) -> None:
        """Integrate one IMU sample held over [self.t, t] (zero-order hold)."""
        dt = float(t) - self.t
        if dt <= 0:
            return
        w_m = np.asarray(w_m, dtype=float)
        a_m = np.asarray(a_m, dtype=float)
        if dt > self.cfg.max_imu_dt:
            self.stats.imu_gaps += 1
            self._propagate_gap(dt)
            self.t = float(t)
            return
        inflate = 1.0
        if (np.any(np.abs(a_m) >= self.cfg.acc_range) or np.any(np.abs(w_m) >= self.cfg.gyro_range)
                or not (np.all(np.isfinite(a_m)) and np.all(np.isfinite(w_m)))):
            # clipped reading: reuse the last good one and trust the prediction much less
            self.stats.saturated += 1
            if self._last_imu is None:
                self._propagate_gap(dt)
                self.t = float(t)
                return
            w_m, a_m = self._last_imu
            inflate = 1e4
        else:
            self._last_imu = (w_m, a_m)
        self.stats.imu_steps += 1
        self._snap()
        w = w_m - self.bg
        a = a_m - self.ba
        R = self.R
        acc_w = R @ a + GRAVITY
        self.p = self.p + self.v * dt + 0.5 * acc_w * dt * dt
        self.v = self.v + acc_w * dt
        dR = so3.exp(w * dt)
        self.R = R @ dR

        F = np.eye(15)
        F[IP, IV] = np.eye(3) * dt
        F[IV, ITH] = -R @ so3.hat(a) * dt
        F[IV, IBA] = -R * dt
        F[ITH, ITH] = dR.T
        F[ITH, IBG] = -np.eye(3) * dt
        q = np.empty(15)
        q[0:3] = 0.25 * self._q_acc * dt**3 * inflate
        q[3:6] = self._q_acc * dt * inflate
        q[6:9] = self._q_gyro * dt * inflate
        q[9:12] = self._q_bg * dt
        q[12:15] = self._q_ba * dt
        self._apply_F(F, q)
        self.t = float(t)

    def propagate_to(self, t: float) -> None:
        """Constant-velocity prediction (no IMU, or bridging a gap)."""
        dt = float(t) - self.t
        if dt <= 0:
            return
        if self.use_imu:
            self._propagate_gap(dt)
        else:
            self._propagate_free(dt, self.cfg.free_acc_std, self.cfg.free_rot_std)
        self.t = float(t)

    def _propagate_gap(self, dt: float) -> None:
        self._propagate_free(dt, self.cfg.gap_acc_std, self.cfg.gap_gyro_std)

    def _propagate_free(self, dt: float, acc_std: float, rot_std: float) -> None:
        self._snap()
        self.p = self.p + self.v * dt
        F = np.eye(15)
        F[IP, IV] = np.eye(3) * dt
        q = np.zeros(15)
        q[0:3] = 0.25 * acc_std**2 * dt**3 + 1e-9
        q[3:6] = acc_std**2 * dt
        if self.yaw_only_motion:
            # nothing observes roll and pitch (no IMU, no VO): let only the heading wander,
            # about the world vertical expressed in the body frame
            up_b = self.R.T @ np.array([0.0, 0.0, 1.0])
            Qth = rot_std**2 * dt * np.outer(up_b, up_b) + 1e-10 * dt * np.eye(3)
        else:
            Qth = None
            q[6:9] = rot_std**2 * dt
        if self.use_imu:
            q[9:12] = self._q_bg * dt
            q[12:15] = self._q_ba * dt
        self._apply_F(F, q, Qth)

    def _apply_F(self, F: np.ndarray, q: np.ndarray, Qth: np.ndarray | None = None) -> None:
        if self.history is not None:
            # consecutive predictions with no update between them collapse into one
            # transition: RTS needs the state only where information entered or is asked for
            if self._acc is None:
                self._acc = [self._post_nominal, self.P[:15, :15].copy(), F]
            else:
                self._acc[2] = F @ self._acc[2]
        self._predict_cov(F, q, Qth)

    def _flush(self) -> None:
        if self.history is not None and self._acc is not None:
            self.history.append([*self._acc, self._nominal(), self.P[:15, :15].copy()])
            self._acc = None

    def _snap(self) -> None:
        if self.history is not None and self._acc is None:
            self._post_nominal = self._nominal()

    def _nominal(self):
        return (self.p.copy(), self.v.copy(), self.R.copy(), self.bg.copy(), self.ba.copy())

    def _predict_cov(self, F: np.ndarray, q: np.ndarray, Qth: np.ndarray | None = None) -> None:
        P = self.P
        A = P[:15, :15]
        P[:15, :15] = F @ A @ F.T + np.diag(q)
        if Qth is not None:
            P[ITH, ITH] += Qth
        cross = F @ P[:15, 15:]
        P[:15, 15:] = cross
        P[15:, :15] = cross.T

    # ------------------------------------------------------------------ cloning
    def clone(self) -> None:
        """Remember the current (p, R) as the reference of the next relative measurement."""
        self.p_c = self.p.copy()
        self.R_c = self.R.copy()
        P = self.P
        J = np.zeros((6, 15))
        J[0:3, 0:3] = np.eye(3)
        J[3:6, 6:9] = np.eye(3)
        top = P[:15, :15]
        P[15:, :15] = J @ top
        P[:15, 15:] = P[15:, :15].T
        P[15:, 15:] = J @ top @ J.T
        self.has_clone = True

    # ------------------------------------------------------------------ updates
    def _update(self, kind: str, r: np.ndarray, H: np.ndarray, Rm: np.ndarray, gate: bool = True) -> bool:
        self._flush()
        P = self.P
        PHt = P @ H.T
        S = H @ PHt + Rm
        S = 0.5 * (S + S.T)
        try:
            Sinv_r = np.linalg.solve(S, r)
        except np.linalg.LinAlgError:
            self.stats.count(kind, False)
            return False
        d2 = float(r @ Sinv_r)
        if not np.isfinite(d2):
            self.stats.count(kind, False)
            return False
        if gate and d2 > chi2.ppf(self.cfg.chi2_prob, len(r)):
            n = self._rejects.get(kind, 0) + 1
            self._rejects[kind] = n
            if n < self.cfg.max_rejects:
                self.stats.count(kind, False)
                return False
            # persistent disagreement: the filter, not the sensor, is probably wrong
            Rm = Rm * max(1.0, d2 / len(r))
            S = H @ PHt + Rm
            S = 0.5 * (S + S.T)
        self._rejects[kind] = 0
        K = np.linalg.solve(S, PHt.T).T
        dx = K @ r
        IKH = np.eye(N) - K @ H
        P = IKH @ P @ IKH.T + K @ Rm @ K.T  # Joseph form keeps P positive definite
        self.P = 0.5 * (P + P.T)
        self._inject(dx)
        self.stats.count(kind, True)
        return True

    def _inject(self, dx: np.ndarray) -> None:
        self.p = self.p + dx[IP]
        self.v = self.v + dx[IV]
        self.R = so3.orthonormalize(self.R @ so3.exp(dx[ITH]))
        if self.use_imu:
            self.bg = self.bg + dx[IBG]
            self.ba = self.ba + dx[IBA]
        self.p_c = self.p_c + dx[ICP]
        self.R_c = so3.orthonormalize(self.R_c @ so3.exp(dx[ICT]))
        # reset Jacobian of the local rotation errors (first order)
        G = np.eye(N)
        G[ITH, ITH] = np.eye(3) - 0.5 * so3.hat(dx[ITH])
        G[ICT, ICT] = np.eye(3) - 0.5 * so3.hat(dx[ICT])
        P = G @ self.P @ G.T
        self.P = 0.5 * (P + P.T)

    def update_position(self, z, std_xyz, kind: str = "gnss", lever_arm=None) -> bool:
        """Position of a point at `lever_arm` (body frame) measured in the world frame."""
        H = np.zeros((3, N))
        H[:, IP] = np.eye(3)
        pred = self.p
        if lever_arm is not None and np.any(lever_arm):
            pred = self.p + self.R @ lever_arm
            H[:, ITH] = -self.R @ so3.hat(lever_arm)
        r = np.asarray(z, dtype=float) - pred
        return self._update(kind, r, H, np.diag(np.asarray(std_xyz, dtype=float) ** 2))

    def update_zero_velocity(self, std: float = 0.02) -> bool:
        H = np.zeros((3, N))
        H[:, IV] = np.eye(3)
        return self._update("zupt", -self.v, H, np.eye(3) * std**2)

    def update_zero_rate(self, w_m, std: float = 2e-3) -> bool:
        """Stationary: the gyro reads only its bias."""
        if not self.use_imu:
            return False
        H = np.zeros((3, N))
        H[:, IBG] = np.eye(3)
        return self._update("zaru", np.asarray(w_m, dtype=float) - self.bg, H, np.eye(3) * std**2)

    def update_yaw(self, yaw_meas: float, forward_body, std: float, kind: str = "heading") -> bool:
        """Heading of a body axis (e.g. the camera's optical axis) projected on the ground."""
        f = self.R @ forward_body
        h2 = f[0] ** 2 + f[1] ** 2
        if h2 < 1e-4:
            return False
        r = np.array([float(so3.wrap_angle(yaw_meas - np.arctan2(f[1], f[0])))])
        # d yaw / d f, then d f / d dtheta = -R hat(forward)
        dyaw_df = np.array([-f[1], f[0], 0.0]) / h2
        H = np.zeros((1, N))
        H[0, ITH] = dyaw_df @ (-self.R @ so3.hat(forward_body))
        return self._update(kind, r, H, np.array([[std**2]]))

    def update_no_sideslip(self, forward_body, std: float) -> bool:
        """Non-holonomic constraint: a car does not slide sideways, so the velocity has no
        component along the body's horizontal axis perpendicular to `forward_body`."""
        up_b = self.R.T @ np.array([0.0, 0.0, 1.0])
        lat = np.cross(up_b, forward_body)
        n = np.linalg.norm(lat)
        if n < 0.3:
            return False
        lat /= n
        vb = self.R.T @ self.v
        H = np.zeros((1, N))
        H[0, IV] = lat @ self.R.T
        H[0, ITH] = lat @ so3.hat(vb)
        return self._update("nhc", np.array([-(lat @ vb)]), H, np.array([[std**2]]))

    def update_relative(self, R_c1c2, u_dir, R_bc, p_bc, rot_std: float, dir_std: float | None) -> bool:
        """VO between the clone (frame 1) and now (frame 2), in camera coordinates.

        R_c1c2: rotation of camera 2 in camera 1. u_dir: unit direction of camera 2's centre
        in camera 1 (None when there is no parallax to trust). R_bc, p_bc: camera in body.
        """
        if not self.has_clone:
            return False
        M = self.R_c.T @ self.R
        R_pred = R_bc.T @ M @ R_bc
        r_rot = so3.log(R_pred.T @ R_c1c2)
        H_rot = np.zeros((3, N))
        H_rot[:, ITH] = R_bc.T
        H_rot[:, ICT] = -R_bc.T @ M.T
        rows_r, rows_H, rows_R = [r_rot], [H_rot], [np.full(3, rot_std**2)]
        if u_dir is not None and dir_std is not None:
            w = self.p - self.p_c + self.R @ p_bc
            d = R_bc.T @ (self.R_c.T @ w - p_bc)
            nd = float(np.linalg.norm(d))
            if nd > 1e-3:
                u = d / nd
                a = np.array([1.0, 0, 0]) if abs(u[0]) < 0.9 else np.array([0, 1.0, 0])
                b1 = np.cross(u, a)
                b1 /= np.linalg.norm(b1)
                b2 = np.cross(u, b1)
                B = np.stack([b1, b2])  # 2x3, orthogonal to the predicted direction
                Jd = np.zeros((3, N))
                A = R_bc.T @ self.R_c.T
                Jd[:, IP] = A
                Jd[:, ICP] = -A
                Jd[:, ITH] = A @ (-self.R @ so3.hat(p_bc))
                Jd[:, ICT] = R_bc.T @ so3.hat(self.R_c.T @ w)
                rows_r.append(B @ np.asarray(u_dir, dtype=float))
                rows_H.append(B @ Jd / nd)
                rows_R.append(np.full(2, dir_std**2))
        r = np.concatenate(rows_r)
        H = np.vstack(rows_H)
        return self._update("vo", r, H, np.diag(np.concatenate(rows_R)))

    # ------------------------------------------------------------------ smoothing
    def mark(self) -> int:
        """Index of the current state in the history (for `smooth`)."""
        self._flush()
        return len(self.history) if self.history is not None else -1

    def smooth(self, marks: list[int]):
        """Rauch-Tung-Striebel pass over the recorded predictions (15 core states).

        Returns, for each mark, the smoothed (p, v, R, bg, ba) and the diagonal of its covariance.
        A mark m is the filtered state after m predictions (and the updates that followed).
        Clone correlations are not carried backwards: with VO this is an approximation.
        """
        self._flush()
        H = self.history
        n = len(H)
        xs = self._nominal()
        Ps = self.P[:15, :15].copy()
        out: dict[int, tuple] = {}
        want = set(marks)
        if n in want:
            out[n] = (xs, np.diag(Ps).copy())
        for j in range(n - 1, -1, -1):
            post, P_post, F, pred, P_pred = H[j]
            d = np.concatenate([xs[0] - pred[0], xs[1] - pred[1], so3.log(pred[2].T @ xs[2]),
                                xs[3] - pred[3], xs[4] - pred[4]])
            C = np.linalg.solve(P_pred.T, (P_post @ F.T).T).T  # P_post F^T P_pred^-1
            dx = C @ d
            xs = (post[0] + dx[0:3], post[1] + dx[3:6], so3.orthonormalize(post[2] @ so3.exp(dx[6:9])),
                  post[3] + dx[9:12], post[4] + dx[12:15])
            Ps = P_post + C @ (Ps - P_pred) @ C.T
            Ps = 0.5 * (Ps + Ps.T)
            if j in want:
                out[j] = (xs, np.diag(Ps).copy())
        return [out[m] for m in marks]

    # ------------------------------------------------------------------ access
    def cov_diag(self) -> np.ndarray:
        return np.diag(self.P)[:15].copy()

    def healthy(self) -> bool:
        P = self.P[:15, :15]
        if not (np.all(np.isfinite(P)) and np.all(np.isfinite(self.p)) and np.all(np.isfinite(self.v))):
            return False
        return bool(np.allclose(P, P.T, atol=1e-9 * max(1.0, np.abs(P).max())))
