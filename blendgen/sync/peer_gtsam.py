"""Peer for the benchmark: GTSAM ISAM2 with IMU preintegration and GPS factors.

One keyframe per GNSS fix: ImuFactor (preintegrated) between keyframes, biases as states with
a BetweenFactor random walk (GTSAM's ImuFactorsExample layout), a robust GPSFactor on each
keyframe, incremental ISAM2 updates with QR factorisation (the default Cholesky reported an
indeterminate system: the IMU information is ~1e9 against unit priors), and the final
(smoothed) estimate interpolated to the camera times.

Given the same vehicle information as blendgen's filter where asked (issue 14): `road` = the
twin's road surface and calib `vehicle.camera_height_m` -> a camera-height factor every
road_height.EVERY_S (camera z = road z under it + camera height, std road_height.ROUGH_STD,
the road's slope in the Jacobian), and `nhc` -> the no-sideslip / zero-vertical-velocity
factor on each keyframe above pipeline.NHC_MIN_SPEED (body-frame lateral and vertical
velocity 0 with pipeline.NHC_LAT_STD / NHC_UP_STD; the IMU is taken as aligned with the
vehicle unless `nhc` is a rotation (blendgen's estimate of the mount), or the mount is a state
of its own with `mount_std_deg`, observed as in blendgen's filter by the no-sideslip factor and
a "level across on average" factor (pipeline.LEVEL_STD) on the same keyframes). The GNSS
receiver model blendgen estimates can be given too:
`latency_s` (a fix stamped t is the antenna at t - latency: its GPS factor sits on a keyframe at
that time), `h_std_scale` (the fixes' horizontal noise times this; not the vertical, as in
blendgen's filter) and `height_corr_s` (the fixes' height-error correlation time: fixes within
it count as one height measurement, vertical std 2 g_std sqrt(corr x rate), as in blendgen's
filter with a calibration), and `odometer` = (speed.csv rows, std, scale, latency): a forward-speed
factor on each keyframe (vehicle-frame forward velocity = scale x the reading at t + latency,
blendgen's estimates of both). Optional dependency (`pip install gtsam`); blendgen's own sync
never imports it.
"""

from __future__ import annotations

import numpy as np

from blendgen import so3
from blendgen.geometry import invert_pose, make_pose
from blendgen.sync import road_height
from blendgen.sync.pipeline import LEVEL_STD, NHC_LAT_STD, NHC_MIN_SPEED, NHC_UP_STD


def run_gtsam(rec, g_t, g_xyz, g_std, out_t, x0, *, prior_sigmas=(1.0, 0.05, 0.1, 1.0),
              road=None, nhc=False, mount_std_deg=None, latency_s: float = 0.0, h_std_scale: float = 1.0,
              height_corr_s: float = 0.0, odometer=None, info: dict | None = None):
    """Camera poses at out_t from IMU + GNSS (world-frame fixes g_xyz at times g_t).

    g_std: the fixes' stated horizontal std (m), one number or one per fix; the factor's
    horizontal sigma is g_std * h_std_scale, the vertical 2 g_std (times sqrt(height_corr_s x
    fix rate) when that is > 1). latency_s: each fix is put at g_t - latency_s. x0 = (p, v,
    R_world_body) initial guess at the first IMU sample; prior_sigmas = (pos m, tilt rad, yaw
    rad, vel m/s). road = (surface, camera_height_m): surface (N, 2) xy -> (N,) road z. nhc:
    vehicle velocity constraint (True: the IMU axes are the vehicle's; a 3x3 R_vehicle_imu:
    in that frame). mount_std_deg = (roll, pitch, yaw) std: with nhc, the mount R_vehicle_imu
    is a state (one Rot3 for the drive) with that prior around `nhc`'s rotation (identity for
    True), estimated with everything else as blendgen's filter does; `info["mount_rpy_deg"]`
    then gets its estimate (roll, pitch, yaw of R_vehicle_imu). Returns a list of T_world_cam.
    """
    import gtsam
    from gtsam.symbol_shorthand import B, V, X

    n = rec.imu_noise
    params = gtsam.PreintegrationParams.MakeSharedU(9.80665)
    params.setAccelerometerCovariance(np.eye(3) * n.accelerometer_noise_density**2)
    params.setGyroscopeCovariance(np.eye(3) * n.gyroscope_noise_density**2)
    params.setIntegrationCovariance(np.eye(3) * 1e-8)
    rw = np.array([n.accelerometer_random_walk] * 3 + [n.gyroscope_random_walk] * 3)

    ip = gtsam.ISAM2Params()
    ip.setFactorization("QR")  # Cholesky reports an indeterminate system: IMU information ~1e9
    isam = gtsam.ISAM2(ip)
    p0, v0, R0 = x0
    imu = rec.imu
    g_t = np.asarray(g_t, float)
    g_std = np.broadcast_to(np.asarray(g_std, float), g_t.shape)
    # the time each fix was measured: the keyframe that carries its GPS factor
    meas_t = g_t - float(latency_s)
    keep = (meas_t > imu[0, 0] + 1e-3) & (meas_t < imu[-1, 0])
    keys_t, key_xyz, key_std = meas_t[keep], np.asarray(g_xyz)[keep], g_std[keep]
    rate = 1.0 / max(float(np.median(np.diff(g_t))), 1e-3) if len(g_t) > 1 else 1.0
    v_factor = 2.0 * np.sqrt(max(float(height_corr_s) * rate, 1.0))
    R_vb = None if nhc is None or isinstance(nhc, bool) else np.asarray(nhc, float)
    use_nhc = nhc is True or R_vb is not None
    mount_key = gtsam.symbol("m", 0) if use_nhc and mount_std_deg is not None else None
    t_prev = imu[0, 0]
    pose = gtsam.Pose3(gtsam.Rot3(R0), gtsam.Point3(*p0))
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    ps, ts, yaws, vs = prior_sigmas
    graph.add(gtsam.PriorFactorPose3(X(0), pose, gtsam.noiseModel.Diagonal.Sigmas(
        np.array([ts, ts, yaws, ps, ps, ps]))))
    graph.add(gtsam.PriorFactorVector(V(0), np.asarray(v0, float), gtsam.noiseModel.Isotropic.Sigma(3, vs)))
    bias0 = gtsam.imuBias.ConstantBias()
    graph.add(gtsam.PriorFactorConstantBias(B(0), bias0, gtsam.noiseModel.Diagonal.Sigmas(
        np.array([0.1, 0.1, 0.1, 0.01, 0.01, 0.01]))))
    values.insert(X(0), pose)
    values.insert(V(0), np.asarray(v0, float))
    values.insert(B(0), bias0)
    if mount_key is not None:
        M0 = gtsam.Rot3(np.eye(3) if R_vb is None else R_vb)
        graph.add(gtsam.PriorFactorRot3(mount_key, M0, gtsam.noiseModel.Diagonal.Sigmas(
            np.radians(np.asarray(mount_std_deg, float)))))
        values.insert(mount_key, M0)
    isam.update(graph, values)
    state = gtsam.NavState(pose, np.asarray(v0, float))
    bias = bias0
    huber = gtsam.noiseModel.mEstimator.Huber.Create(1.5)
    j = 1  # next IMU sample
    times = [t_prev]
    T_bc = invert_pose(rec.T_cam_imu)
    road_model = None if road is None else road_height.RoadHeight(road[0], "camera", float(road[1]), 0.0)
    next_road_t = -np.inf
    for k, tk in enumerate(keys_t, start=1):
        pim = gtsam.PreintegratedImuMeasurements(params, bias)
        t = t_prev
        while j < len(imu) and imu[j, 0] <= tk:
            dt = imu[j, 0] - t
            if dt > 0:
                pim.integrateMeasurement(imu[j, 4:7], imu[j, 1:4], dt)
            t = imu[j, 0]
            j += 1
        if tk - t > 0 and j < len(imu):
            pim.integrateMeasurement(imu[j, 4:7], imu[j, 1:4], tk - t)
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        graph.add(gtsam.ImuFactor(X(k - 1), V(k - 1), X(k), V(k), B(k - 1), pim))
        # bias random walk between keyframes
        graph.add(gtsam.BetweenFactorConstantBias(B(k - 1), B(k), gtsam.imuBias.ConstantBias(),
                                                  gtsam.noiseModel.Diagonal.Sigmas(rw * np.sqrt(tk - t_prev))))
        sh, sv = key_std[k - 1] * h_std_scale, v_factor * key_std[k - 1]
        gps_noise = gtsam.noiseModel.Robust.Create(huber, gtsam.noiseModel.Diagonal.Sigmas(np.array([sh, sh, sv])))
        graph.add(gtsam.GPSFactor(X(k), gtsam.Point3(*key_xyz[k - 1]), gps_noise))
        if road_model is not None and tk >= next_road_t:  # as often as blendgen's filter applies it
            graph.add(_road_factor(gtsam, X(k), road_model, T_bc[:3, 3]))
            next_road_t = tk + road_height.EVERY_S
        if use_nhc and np.linalg.norm(state.velocity()) > NHC_MIN_SPEED:
            graph.add(_vehicle_velocity_factor(gtsam, X(k), V(k), [1, 2], np.zeros(2), [NHC_LAT_STD, NHC_UP_STD],
                                               R_vb, mount_key))
            if mount_key is not None:  # what observes the mount's roll, as in blendgen's filter
                graph.add(_level_factor(gtsam, X(k), mount_key))
        if odometer is not None:
            sp, sp_std, sp_scale, sp_lat = odometer
            if sp[0, 0] <= tk + sp_lat <= sp[-1, 0]:
                target = sp_scale * np.interp(tk + sp_lat, sp[:, 0], sp[:, 1])
                graph.add(_vehicle_velocity_factor(gtsam, X(k), V(k), [0], np.array([target]), [sp_std],
                                                   R_vb, mount_key))
        pred = pim.predict(state, bias)
        values.insert(X(k), pred.pose())
        values.insert(V(k), pred.velocity())
        values.insert(B(k), bias)
        isam.update(graph, values)
        est = isam.calculateEstimate()
        state = gtsam.NavState(est.atPose3(X(k)), est.atVector(V(k)))
        bias = est.atConstantBias(B(k))
        t_prev = tk
        times.append(tk)
    est = isam.calculateEstimate()
    if mount_key is not None and info is not None:
        info["mount_rpy_deg"] = np.degrees(est.atRot3(mount_key).rpy()).tolist()
    if info is not None and info.get("want_h_std"):  # the MAP's own horizontal std (RMS over keys)
        var = []
        for k in range(0, len(times), 10):
            R = est.atPose3(X(k)).rotation().matrix()
            S = R @ isam.marginalCovariance(X(k))[3:, 3:] @ R.T  # Pose3 tangent: rotation, then translation
            var.append(S[0, 0] + S[1, 1])
        info["h_std_m"] = float(np.sqrt(np.mean(var)))
    Ts = [est.atPose3(X(k)).matrix() for k in range(len(times))]
    return _interp_cam(np.array(times), Ts, np.asarray(out_t), invert_pose(rec.T_cam_imu))


def _road_factor(gtsam, key, road, p_bc):
    """Camera height above the road: r = z_cam - z_road(xy_cam) - h. Pose3's tangent is
    [rotation, translation] in the body frame, so d p_cam = -R [p_bc]x dw + R dv."""

    def err(this, values, H):
        T = values.atPose3(this.keys()[0])
        R, t = T.rotation().matrix(), T.translation()
        q = t + R @ p_bc
        tgt = road.target(q[:2])
        if tgt is None:  # off the twin: no information
            if H is not None:
                H[0] = np.zeros((1, 6))
            return np.zeros(1)
        z, _, grad = tgt
        J = np.hstack([-R @ so3.hat(p_bc), R])
        if H is not None:
            H[0] = (J[2] - grad @ J[:2])[None, :]
        return np.array([q[2] - z])

    return gtsam.CustomFactor(gtsam.noiseModel.Isotropic.Sigma(1, road_height.ROUGH_STD), [key], err)


def _vehicle_velocity_factor(gtsam, xkey, vkey, rows, target, sigmas, R_vb=None, mount_key=None):
    """Vehicle-frame velocity components `rows` equal `target`: no-sideslip (rows 1, 2 zero) or
    the odometer (row 0): r = (M R^T v)[rows] - target with M = R_vb (the IMU's rotation into
    the vehicle frame, x forward; identity when None) or the state `mount_key`;
    d/dw = M [R^T v]x, d/dv = M R^T, d/dm = -M [R^T v]x (M exp(dm))."""
    M_fixed = np.eye(3) if R_vb is None else np.asarray(R_vb, float)
    keys = [xkey, vkey] + ([mount_key] if mount_key is not None else [])

    def err(this, values, H):
        R = values.atPose3(this.keys()[0]).rotation().matrix()
        v = values.atVector(this.keys()[1])
        M = values.atRot3(this.keys()[2]).matrix() if mount_key is not None else M_fixed
        vb = R.T @ v
        if H is not None:
            Mv = (M @ so3.hat(vb))[rows]
            H[0] = np.hstack([Mv, np.zeros((len(rows), 3))])
            H[1] = (M @ R.T)[rows]
            if mount_key is not None:
                H[2] = -Mv
        return (M @ vb)[rows] - target

    return gtsam.CustomFactor(gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sigmas, float)), keys, err)


def _level_factor(gtsam, xkey, mount_key):
    """The vehicle is level across on average (pipeline.LEVEL_STD): r = z of the vehicle's
    lateral axis in the world, R M^T e_y; d/dw = -R [M^T e_y]x, d/dm = R [M^T e_y]x."""
    e_y = np.array([0.0, 1.0, 0.0])

    def err(this, values, H):
        R = values.atPose3(this.keys()[0]).rotation().matrix()
        y_b = values.atRot3(this.keys()[1]).matrix().T @ e_y
        if H is not None:
            J = (R @ so3.hat(y_b))[2]
            H[0] = np.hstack([-J, np.zeros(3)])[None, :]
            H[1] = J[None, :]
        return np.array([(R @ y_b)[2]])

    return gtsam.CustomFactor(gtsam.noiseModel.Isotropic.Sigma(1, LEVEL_STD), [xkey, mount_key], err)


def _interp_cam(times, T_wb, out_t, T_bc):
    out = []
    for t in out_t:
        i = int(np.clip(np.searchsorted(times, t) - 1, 0, len(times) - 2))
        a = float(np.clip((t - times[i]) / (times[i + 1] - times[i]), 0.0, 1.0))
        A, Bm = T_wb[i], T_wb[i + 1]
        R = A[:3, :3] @ so3.exp(a * so3.log(A[:3, :3].T @ Bm[:3, :3]))
        p = (1 - a) * A[:3, 3] + a * Bm[:3, 3]
        out.append(make_pose(R, p) @ T_bc)
    return out
