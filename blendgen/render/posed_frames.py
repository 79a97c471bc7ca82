"""Frames of a built-in twin rendered at known camera poses (ground truth for the camera
estimate's tests and benchmark). bpy: only import from a process that may load Blender.

`render_posed_frames(out_dir, poses, camera)` renders each missing `<name>.png` once and
writes `poses.json` (name -> height, pitch, roll, yaw, T_world_cam) beside them, so a
second call with the same poses costs nothing.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from blendgen import atomic
from blendgen.geometry import Camera, R_world_cam_from_ypr, make_pose

SUN = {"sun_direction": [0.45, -0.35, 0.82], "sun_strength": 3.0, "sun_color": [1, 1, 1], "sun_angle_deg": 0.5,
       "sky_color": [0.5, 0.6, 0.8], "sky_strength": 1.0, "sun_visible": True}


def route_poses(twin_path: Path, specs: list[dict]) -> dict[str, dict]:
    """Camera poses on the twin's lanes: each spec has name, seed (which lane/place), s (metres
    along the route), height_m, pitch_deg, roll_deg and yaw_deg (offset from the lane direction)."""
    from blendgen.twin.model import load_twin

    twin = load_twin(twin_path)
    out = {}
    for sp in specs:
        route = twin.ego_route(40.0, int(sp.get("seed", 0)))
        i = int(sp.get("s", 0))
        fwd = route[min(i + 5, len(route) - 1)] - route[i]
        yaw = math.atan2(fwd[1], fwd[0]) + math.radians(sp.get("yaw_deg", 0.0))
        R = R_world_cam_from_ypr(yaw, math.radians(sp["pitch_deg"]), math.radians(sp["roll_deg"]))
        T = make_pose(R, [route[i][0], route[i][1], sp["height_m"]])
        out[sp["name"]] = {**sp, "T_world_cam": T.tolist()}
    return out


def render_posed_frames(out_dir: Path, specs: list[dict], camera: Camera, *, samples: int = 4,
                        twin: str = "demo_town") -> dict[str, dict]:
    from blendgen.job.schema import BUILTIN_TWINS_DIR, Render

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    twin_path = BUILTIN_TWINS_DIR / f"{twin}.yaml"
    poses = route_poses(twin_path, specs)
    todo = [n for n in poses if not (out_dir / f"{n}.png").exists()]
    if todo:
        from blendgen.render.session import RenderSession

        s = RenderSession(twin_path, None, Render(samples=samples, denoise=False), camera)
        try:
            for n in todo:
                s.render_background(np.array(poses[n]["T_world_cam"]), SUN, out_dir / f"{n}.png", samples)
        finally:
            s.close()
    meta = {"camera": camera.to_dict(), "twin": twin, "poses": poses}
    atomic.write_json(out_dir / "poses.json", meta, indent=1)
    return poses
