"""Error-state EKF: IMU propagation on SO(3), position / zero-velocity / relative-pose updates.

Nominal state: position p, velocity v (world, z up), orientation R = R_world_body, gyro bias
bg, accelerometer bias ba, and calibration quantities that are constant over a drive:
the mounting rotation R_bv of the vehicle frame (x forward, z up: the frame in which the car
neither slides sideways nor jumps) in the IMU body frame, the GNSS receiver latency tau (a fix
stamped t is the antenna's position at t - tau), the antenna lever arm (body frame), and the
scale k and latency L of the vehicle's odometer (a reading stamped t is the forward speed at
t - L divided by k).
Error state (24): [dp, dv, dtheta, dbg, dba, dmount, dtau, dlever, dk, dL] with the rotation errors
local to their frames, R_true = R Exp(dtheta), R_bv_true = R_bv Exp(dmount). Calibration states
are estimated only after `enable_calibration` (else decoupled and frozen). Six more error
entries hold a stochastic clone of (p, theta) at the last camera frame, so visual odometry
(relative rotation and translation direction between two frames) enters as a proper relative
measurement.

Every update uses the Joseph form, is chi-square gated and symmetrised. A measurement the gate
keeps rejecting stays rejected (counted in the stats): re-accepting it with inflated noise
let an inconsistent sensor win (97 of 314 VO pairs on a stabilised action-camera clip). GNSS,
the only absolute sensor, is the exception the pipeline makes: when its fixes agree with each
other for GNSS_REOPEN_S but not with the filter, `reopen` widens the filter instead.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2

from blendgen import so3

GRAVITY = np.array([0.0, 0.0, -9.80665])
NC = 24  # core error states (15 navigation + 9 calibration)
N = NC + 6  # + clone (dp_c, dtheta_c)
IP, IV, ITH, IBG, IBA = slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12), slice(12, 15)
IM, ITAU, ILA = slice(15, 18), slice(18, 19), slice(19, 22)  # mount, GNSS latency, lever arm
IK, IL = slice(22, 23), slice(23, 24)  # odometer scale and latency
ICP, ICT = slice(24, 27), slice(27, 30)
CALIB = slice(15, 24)


@dataclass
class EkfConfig:
    acc_noise: float = 2.0e-3     # m/s^2/sqrt(Hz)   (Kalibr accelerometer_noise_density)
    gyro_noise: float = 1.7e-4    # rad/s/sqrt(Hz)
    acc_walk: float = 3.0e-3      # m/s^3/sqrt(Hz)
    gyro_walk: float = 2.0e-5     # rad/s^2/sqrt(Hz)
    noise_inflation: float = 1.0  # >1 when calib.yaml gives raw datasheet densities (Kalibr advises inflating)
    # the odometer's scale as a slow random walk (per sqrt(s); tyre pressure, temperature,
    # slip), and so that an early misfit does not harden: on comma2k19 the first 10 s are one
    # steady acceleration, where scale and latency trade off (scale 1.0036 against 1.0087), and
    # held constant that scale carried 3.5 m into a 40 s GNSS outage, rejecting the fixes after it
    speed_scale_walk: float = 3e-4
    max_imu_dt: float = 0.05      # a longer IMU interval is a gap: no integration across it
    gap_acc_std: float = 2.0      # m/s^2: how much the vehicle may accelerate unseen in a gap
    gap_gyro_std: float = 0.2     # rad/s: how much it may turn unseen in a gap
    acc_range: float = 156.0      # m/s^2 (16 g): a reading at or beyond it is saturated
    gyro_range: float = 34.0      # rad/s (~2000 deg/s)
    free_acc_std: float = 3.0     # without IMU: constant-velocity model, acceleration noise
    free_rot_std: float = 0.5     # without IMU: orientation random walk, rad/s/sqrt(Hz)
    chi2_prob: float = 0.9995


@dataclass
class EkfStats:
    imu_steps: int = 0
    imu_gaps: int = 0
    saturated: int = 0
    updates: dict = field(default_factory=dict)
    rejected: dict = field(default_factory=dict)
    # per kind: negative log-likelihood of the innovations, 0.5 (r' S^-1 r + log det S) without
    # the constant (the prediction-error decomposition; profiled over fixed calibrations)
    nll: dict = field(default_factory=dict)
    nis: dict = field(default_factory=dict)  # per kind: sum of r' S^-1 r of the accepted ones

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
        self.R_bv = np.eye(3)
        self.tau = 0.0
        self.lever = np.zeros(3)
        self.speed_scale = 1.0
        self.speed_latency = 0.0
        self.calibrating = False
        self.yaw_only_motion = False  # without IMU and VO: roll/pitch stay as initialised
        self.P = np.eye(N) * 1e-6
        self.P[:15, :15] = np.diag(np.asarray(P0_diag, dtype=float))
        self.P[CALIB, CALIB] = np.eye(9) * 1e-12
        if not use_imu:  # biases are meaningless without an IMU: freeze them
            self.P[IBG, IBG] = np.eye(3) * 1e-12
            self.P[IBA, IBA] = np.eye(3) * 1e-12
        self.p_c = self.p.copy()
        self.R_c = self.R.copy()
        self.has_clone = False
        self.stats = EkfStats()
        self.history: list | None = None  # set to [] to record what the RTS smoother needs
        self._acc = None
        self._last_imu = None  # last valid (w, a) for saturated samples
        self._last_innovation = None  # (r, S) of the last update
        k = cfg.noise_inflation
        self._q_acc, self._q_gyro = (k * cfg.acc_noise) ** 2, (k * cfg.gyro_noise) ** 2
        self._q_ba, self._q_bg = (k * cfg.acc_walk) ** 2, (k * cfg.gyro_walk) ** 2
        self._q_k = 0.0  # the odometer scale's walk, once enable_calibration estimates it
        self.noise_scale = 1.0  # on the IMU's white-noise variances (the pipeline raises it in GNSS outages)

    def enable_calibration(self, R_bv, mount_std, tau: float, tau_std: float, lever, lever_std,
                           speed_scale_std: float = 0.0, speed_latency: float = 0.0,
                           speed_latency_std: float = 0.0, speed_scale: float = 1.0) -> None:
        """Estimate the mount (prior R_bv, per-axis std in rad), GNSS latency, lever arm and the
        odometer's scale and latency."""
        self.R_bv = so3.orthonormalize(np.asarray(R_bv, dtype=float))
        self.tau = float(tau)
        self.lever = np.asarray(lever, dtype=float).copy()
        self.speed_scale = float(speed_scale)
        self.speed_latency = float(speed_latency)
        std = np.concatenate([np.broadcast_to(mount_std, 3), [tau_std], np.broadcast_to(lever_std, 3),
                              [speed_scale_std, speed_latency_std]])
        self.P[CALIB, :] = 0.0
        self.P[:, CALIB] = 0.0
        self.P[CALIB, CALIB] = np.diag(np.maximum(std, 1e-6) ** 2)
        self._q_k = self.cfg.speed_scale_walk**2 if speed_scale_std > 0 else 0.0
        self.calibrating = True

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
        inflate = self.noise_scale
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

        F = np.eye(NC)
        F[IP, IV] = np.eye(3) * dt
        F[IV, ITH] = -R @ so3.hat(a) * dt
        F[IV, IBA] = -R * dt
        F[ITH, ITH] = dR.T
        F[ITH, IBG] = -np.eye(3) * dt
        q = np.zeros(NC)
        q[0:3] = 0.25 * self._q_acc * dt**3 * inflate
        q[3:6] = self._q_acc * dt * inflate
        q[6:9] = self._q_gyro * dt * inflate
        q[9:12] = self._q_bg * dt
        q[12:15] = self._q_ba * dt
        q[IK] = self._q_k * dt
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
        F = np.eye(NC)
        F[IP, IV] = np.eye(3) * dt
        q = np.zeros(NC)
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

    def reopen(self, pos_var, vel_var: float) -> None:
        """Widen the position and velocity uncertainty by `pos_var` (3,) and `vel_var`: the
        filter drifted away from GNSS fixes that agree with each other, and the gate would keep
        rejecting the only absolute sensor. Entered as process noise of an identity step, so the
        smoother sees it."""
        self._snap()
        q = np.zeros(NC)
        q[IP] = pos_var
        q[IV] = vel_var
        self._apply_F(np.eye(NC), q)

    def _apply_F(self, F: np.ndarray, q: np.ndarray, Qth: np.ndarray | None = None) -> None:
        if self.history is not None:
            # consecutive predictions with no update between them collapse into one
            # transition: RTS needs the state only where information entered or is asked for
            if self._acc is None:
                self._acc = [self._post_nominal, self.P[:NC, :NC].copy(), F]
            else:
                self._acc[2] = F @ self._acc[2]
        self._predict_cov(F, q, Qth)

    def _flush(self) -> None:
        if self.history is not None and self._acc is not None:
            self.history.append([*self._acc, self._nominal(), self.P[:NC, :NC].copy()])
            self._acc = None

    def _snap(self) -> None:
        if self.history is not None and self._acc is None:
            self._post_nominal = self._nominal()

    def _nominal(self):
        return (self.p.copy(), self.v.copy(), self.R.copy(), self.bg.copy(), self.ba.copy(), self.R_bv.copy(),
                self.tau, self.lever.copy(), self.speed_scale, self.speed_latency)

    def _predict_cov(self, F: np.ndarray, q: np.ndarray, Qth: np.ndarray | None = None) -> None:
        P = self.P
        A = P[:NC, :NC]
        P[:NC, :NC] = F @ A @ F.T + np.diag(q)
        if Qth is not None:
            P[ITH, ITH] += Qth
        cross = F @ P[:NC, NC:]
        P[:NC, NC:] = cross
        P[NC:, :NC] = cross.T

    # ------------------------------------------------------------------ cloning
    def clone(self) -> None:
        """Remember the current (p, R) as the reference of the next relative measurement."""
        self.p_c = self.p.copy()
        self.R_c = self.R.copy()
        P = self.P
        J = np.zeros((6, NC))
        J[0:3, IP] = np.eye(3)
        J[3:6, ITH] = np.eye(3)
        top = P[:NC, :NC]
        P[NC:, :NC] = J @ top
        P[:NC, NC:] = P[NC:, :NC].T
        P[NC:, NC:] = J @ top @ J.T
        self.has_clone = True

    # ------------------------------------------------------------------ updates
    def _update(self, kind: str, r: np.ndarray, H: np.ndarray, Rm: np.ndarray, gate: bool = True) -> bool:
        self._flush()
        if not self.calibrating:
            H = H.copy()
            H[:, CALIB] = 0.0  # frozen calibration: keep it decoupled
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
        self._last_innovation = (r, S)
        if not np.isfinite(d2):
            self.stats.count(kind, False)
            return False
        if gate and d2 > (g := chi2.ppf(self.cfg.chi2_prob, len(r))):
            # a rejected one costs what the gate allows (a robust, continuous cost in the
            # calibration a profile is taken over)
            self.stats.nll[kind] = self.stats.nll.get(kind, 0.0) + 0.5 * (g + float(np.linalg.slogdet(S)[1]))
            self.stats.count(kind, False)
            return False
        self.stats.nll[kind] = self.stats.nll.get(kind, 0.0) + 0.5 * (d2 + float(np.linalg.slogdet(S)[1]))
        self.stats.nis[kind] = self.stats.nis.get(kind, 0.0) + d2
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
        if self.calibrating:
            self.R_bv = so3.orthonormalize(self.R_bv @ so3.exp(dx[IM]))
            self.tau = self.tau + float(dx[ITAU][0])
            self.lever = self.lever + dx[ILA]
            self.speed_scale = self.speed_scale + float(dx[IK][0])
            self.speed_latency = self.speed_latency + float(dx[IL][0])
        self.p_c = self.p_c + dx[ICP]
        self.R_c = so3.orthonormalize(self.R_c @ so3.exp(dx[ICT]))
        # reset Jacobian of the local rotation errors (first order)
        G = np.eye(N)
        G[ITH, ITH] = np.eye(3) - 0.5 * so3.hat(dx[ITH])
        G[IM, IM] = np.eye(3) - 0.5 * so3.hat(dx[IM])
        G[ICT, ICT] = np.eye(3) - 0.5 * so3.hat(dx[ICT])
        P = G @ self.P @ G.T
        self.P = 0.5 * (P + P.T)

    def update_position(self, z, std_xyz, kind: str = "gnss", lever_arm=None) -> bool:
        """Position of a point at `lever_arm` (body frame; default: the estimated antenna lever
        arm) measured in the world frame, `tau` seconds late (the latency state)."""
        la = self.lever if lever_arm is None else np.asarray(lever_arm, dtype=float)
        H = np.zeros((3, N))
        H[:, IP] = np.eye(3)
        # a fix stamped now is where the antenna was tau ago: p + R la - tau (v + w x R la),
        # the rotation term neglected (tau * turn rate * lever arm: millimetres)
        pred = self.p + self.R @ la - self.tau * self.v
        H[:, ITH] = -self.R @ so3.hat(la)
        H[:, IV] = -self.tau * np.eye(3)
        H[:, ITAU] = -self.v[:, None]
        H[:, ILA] = self.R
        r = np.asarray(z, dtype=float) - pred
        ok = self._update(kind, r, H, np.diag(np.asarray(std_xyz, dtype=float) ** 2))
        if ok:  # the horizontal part alone (chi-square, 2 dof): how consistent the stated noise is
            r, S = self._last_innovation
            self.stats.nis[kind + "_h"] = self.stats.nis.get(kind + "_h", 0.0) + float(
                r[:2] @ np.linalg.solve(S[:2, :2], r[:2]))
        return ok

    def update_height(self, z, std: float, point_b=None, slope_xy=(0.0, 0.0), kind: str = "road",
                      max_residual: float | None = None) -> bool:
        """Height of a body point (`point_b`, body frame; default: the antenna lever arm state)
        above a surface: z measured, the surface rising by slope_xy (dz/dx, dz/dy) where the
        point moves horizontally (so a position error along a slope is not a height error).
        max_residual: gate in metres instead of chi-square (a physical constraint that must
        pull an overconfident vertical channel back; beyond it the surface is the wrong one)."""
        antenna = point_b is None
        la = self.lever if antenna else np.asarray(point_b, dtype=float)
        q = self.p + self.R @ la
        H = np.zeros((1, N))
        g = np.array([-slope_xy[0], -slope_xy[1], 1.0])
        H[0, IP] = g
        H[0, ITH] = g @ (-self.R @ so3.hat(la))
        if antenna:
            H[0, ILA] = g @ self.R
        r = np.array([float(z) - q[2]])
        if max_residual is not None and not abs(r[0]) <= max_residual:
            self._flush()
            self.stats.count(kind, False)
            return False
        return self._update(kind, r, H, np.array([[std**2]]), gate=max_residual is None)

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

    def _vehicle_velocity(self):
        """The velocity in the vehicle frame, vv = R_bv^T R^T v, its body-frame form and its
        Jacobian (3 x N: velocity, attitude, mount)."""
        vb = self.R.T @ self.v
        vv = self.R_bv.T @ vb
        H = np.zeros((3, N))
        H[:, IV] = self.R_bv.T @ self.R.T
        H[:, ITH] = self.R_bv.T @ so3.hat(vb)
        H[:, IM] = so3.hat(vv)
        return vv, H

    def update_vehicle_velocity(self, std_lat: float, std_up: float) -> bool:
        """Non-holonomic constraint in the vehicle frame (the mount R_bv applied): a car neither
        slides sideways nor leaves the road surface, so its velocity has no y or z component
        there. With the mount estimated this makes the mount's pitch and yaw observable."""
        vv, H = self._vehicle_velocity()
        return self._update("nhc", -vv[1:3], H[1:3], np.diag([std_lat**2, std_up**2]))

    def update_vehicle_speed(self, reading: float, std: float, f_b) -> bool:
        """The odometer (CAN wheel speed): a reading is the vehicle frame's forward velocity L
        seconds ago over k (k: tyre radius, L: the odometer's clock against the IMU's; both
        calibration states): k reading = v_x - L a_x, a_x the forward acceleration from the
        specific force f_b (body frame, averaged over the reading's interval)."""
        vv, Hv = self._vehicle_velocity()
        g_b = self.R.T @ GRAVITY
        a_v = self.R_bv.T @ (np.asarray(f_b, dtype=float) - self.ba + g_b)  # acceleration, vehicle frame
        L = self.speed_latency
        H = Hv[:1].copy()  # of h = v_x - L a_x
        H[0, ITH] -= L * (self.R_bv.T @ so3.hat(g_b))[0]
        H[0, IBA] = L * self.R_bv.T[0]
        H[0, IM] -= L * so3.hat(a_v)[0]
        H[0, IK] = -reading
        H[0, IL] = -a_v[0]
        r = np.array([self.speed_scale * reading - vv[0] + L * a_v[0]])
        return self._update("speed", r, H, np.array([[std**2]]))

    def update_vehicle_level(self, std: float) -> bool:
        """Weak prior that the vehicle frame's roll is zero (roads are level across on average):
        the only thing that observes the mount's roll on a drive without a calibration stop."""
        y_w = self.R @ self.R_bv[:, 1]  # vehicle's lateral axis in the world
        H = np.zeros((1, N))
        # d(y_w)/d(dtheta) = -R hat(R_bv y) ; d(y_w)/d(dmount) = -R R_bv hat(e_y)
        H[0, ITH] = -(self.R @ so3.hat(self.R_bv[:, 1]))[2]
        H[0, IM] = -(self.R @ self.R_bv @ so3.hat(np.array([0.0, 1.0, 0.0])))[2]
        return self._update("level", np.array([-y_w[2]]), H, np.array([[std**2]]))

    def predicted_travel(self, R_bc, p_bc) -> np.ndarray:
        """The camera's travel from the clone to now (m), in the clone's camera axes."""
        w = self.p - self.p_c + self.R @ p_bc
        return R_bc.T @ (self.R_c.T @ w - p_bc)

    def update_relative(self, R_c1c2, u_dir, R_bc, p_bc, rot_std, dir_std) -> bool:
        """VO between the clone (frame 1) and now (frame 2), in camera coordinates.

        R_c1c2: rotation of camera 2 in camera 1. u_dir: unit direction of camera 2's centre
        in camera 1 (None when there is no parallax to trust). R_bc, p_bc: camera in body.
        rot_std: a std (rad) or a 3x3 covariance of the right rotation error of R_c1c2;
        dir_std: a std (rad) or a 3x3 covariance of u_dir (projected on its tangent plane).
        """
        if not self.has_clone:
            return False
        M = self.R_c.T @ self.R
        R_pred = R_bc.T @ M @ R_bc
        r_rot = so3.log(R_pred.T @ R_c1c2)
        H_rot = np.zeros((3, N))
        H_rot[:, ITH] = R_bc.T
        H_rot[:, ICT] = -R_bc.T @ M.T
        rot_cov = np.asarray(rot_std, dtype=float)
        rot_cov = np.eye(3) * rot_cov**2 if rot_cov.ndim == 0 else rot_cov
        rows_r, rows_H, blocks = [r_rot], [H_rot], [rot_cov]
        if u_dir is not None and dir_std is not None:
            d = self.predicted_travel(R_bc, p_bc)
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
                Jd[:, ICT] = R_bc.T @ so3.hat(R_bc @ d + p_bc)  # R_c^T (p - p_c + R p_bc)
                rows_r.append(B @ np.asarray(u_dir, dtype=float))
                rows_H.append(B @ Jd / nd)
                dc = np.asarray(dir_std, dtype=float)
                blocks.append(np.eye(2) * dc**2 if dc.ndim == 0 else B @ dc @ B.T)
        r = np.concatenate(rows_r)
        H = np.vstack(rows_H)
        Rm = np.zeros((len(r), len(r)))
        k = 0
        for blk in blocks:
            Rm[k:k + len(blk), k:k + len(blk)] = blk
            k += len(blk)
        return self._update("vo", r, H, 0.5 * (Rm + Rm.T))

    # ------------------------------------------------------------------ smoothing
    def mark(self) -> int:
        """Index of the current state in the history (for `smooth`)."""
        self._flush()
        return len(self.history) if self.history is not None else -1

    def smooth(self, marks: list[int]):
        """Rauch-Tung-Striebel pass over the recorded predictions (the 24 core states).

        Returns, for each mark, the smoothed (p, v, R, bg, ba, R_bv, tau, lever, odometer scale,
        odometer latency) and the diagonal of its covariance.
        A mark m is the filtered state after m predictions (and the updates that followed).
        Clone correlations are not carried backwards: with VO this is an approximation.
        """
        self._flush()
        H = self.history
        n = len(H)
        xs = self._nominal()
        Ps = self.P[:NC, :NC].copy()
        out: dict[int, tuple] = {}
        want = set(marks)
        if n in want:
            out[n] = (xs, np.diag(Ps).copy())
        for j in range(n - 1, -1, -1):
            post, P_post, F, pred, P_pred = H[j]
            d = np.concatenate([xs[0] - pred[0], xs[1] - pred[1], so3.log(pred[2].T @ xs[2]),
                                xs[3] - pred[3], xs[4] - pred[4], so3.log(pred[5].T @ xs[5]),
                                [xs[6] - pred[6]], xs[7] - pred[7], [xs[8] - pred[8], xs[9] - pred[9]]])
            C = np.linalg.solve(P_pred.T, (P_post @ F.T).T).T  # P_post F^T P_pred^-1
            dx = C @ d
            xs = (post[0] + dx[IP], post[1] + dx[IV], so3.orthonormalize(post[2] @ so3.exp(dx[ITH])),
                  post[3] + dx[IBG], post[4] + dx[IBA], so3.orthonormalize(post[5] @ so3.exp(dx[IM])),
                  post[6] + float(dx[ITAU][0]), post[7] + dx[ILA], post[8] + float(dx[IK][0]),
                  post[9] + float(dx[IL][0]))
            Ps = P_post + C @ (Ps - P_pred) @ C.T
            Ps = 0.5 * (Ps + Ps.T)
            if j in want:
                out[j] = (xs, np.diag(Ps).copy())
        return [out[m] for m in marks]

    # ------------------------------------------------------------------ access
    def cov_diag(self) -> np.ndarray:
        return np.diag(self.P)[:NC].copy()

    def healthy(self) -> bool:
        P = self.P[:NC, :NC]
        if not (np.all(np.isfinite(P)) and np.all(np.isfinite(self.p)) and np.all(np.isfinite(self.v))):
            return False
        return bool(np.allclose(P, P.T, atol=1e-9 * max(1.0, np.abs(P).max())))
