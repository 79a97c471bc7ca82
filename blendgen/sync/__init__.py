"""Sync stage: camera pose of every frame in the twin frame (bpy-free).

lut (GNSS -> twin), visual odometry from `blendgen.vo`, ekf (error-state EKF + RTS smoother),
reanchor (drift correction against the global fixes), pipeline.run_sync (the stage),
command (`blendgen sync`), metrics/simulate (evaluation and synthetic drives), peer_gtsam
(benchmark peer, optional gtsam).
"""
