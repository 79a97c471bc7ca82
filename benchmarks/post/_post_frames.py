"""Render the 1280x720 frames that bench_post.py --timing composites (cached in a folder).

Run in its own process (it imports bpy through RenderSession):
    python benchmarks/post/_post_frames.py OUT_DIR [N_FRAMES]
Each frame: 3-4 procedural objects (assets_procedural builders) with sun shadows on the
ground-plane road, outputs rgba, index, shadow_catcher, lighting, 8 spp + OIDN, the render
driver's region; the plans move the objects so that some frames put them at the edges.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: its blendgen

from blendgen.geometry import Camera, R_world_cam_from_ypr, make_pose  # noqa: E402
from blendgen.job.schema import Render  # noqa: E402
from blendgen.plan import FramePlan, PlacedObject  # noqa: E402

SUN = {"sun_direction": [0.45, -0.35, 0.82], "sun_strength": 3.0, "sun_color": [1.0, 0.97, 0.92],
       "sun_angle_deg": 0.53, "sky_color": [0.5, 0.6, 0.8], "sky_strength": 1.0, "sun_visible": True}
T = make_pose(R_world_cam_from_ypr(0.0, -0.03), [0.0, 0.0, 1.5])
LAYOUTS = [  # (cls, x ahead, y left, yaw, dims); 3-4 objects per frame
    [("car", 14.0, 2.0, 0.2, (4.5, 1.8, 1.5)), ("person", 9.0, -2.5, 0.0, (0.5, 0.6, 1.8)),
     ("truck", 28.0, -3.5, 0.0, (9.0, 2.5, 3.5)), ("bicycle", 11.0, -4.5, 1.3, (1.8, 0.6, 1.1))],
    [("car", 9.0, 6.2, 1.4, (4.5, 1.8, 1.5)), ("car", 12.0, -8.0, 3.1, (4.5, 1.8, 1.5)),  # at the edges
     ("person", 20.0, 0.5, 0.0, (0.5, 0.6, 1.8))],
    [("bus", 24.0, 3.5, 0.1, (11.0, 2.6, 3.2)), ("motorcycle", 10.0, -1.5, 0.0, (2.1, 0.8, 1.3)),
     ("person", 7.0, 3.8, 1.0, (0.5, 0.6, 1.8)), ("car", 16.0, -4.0, 0.0, (4.5, 1.8, 1.5))],
]


def main():
    from assets_procedural.objects import build_object
    from blendgen.render.session import RenderSession

    out = Path(sys.argv[1])
    n = int(sys.argv[2]) if len(sys.argv) > 2 else len(LAYOUTS)
    out.mkdir(parents=True, exist_ok=True)
    cam = Camera.from_hfov(1280, 720, 70)
    sess = RenderSession(None, None, Render(samples=8, denoise=True), cam, object_builder=build_object)
    for f, lay in enumerate(LAYOUTS[:n]):
        path = out / f"frame{f}.exr"
        if path.is_file():
            continue
        objs = [PlacedObject(10 * f + j + 1, c, (x, y, 0.0), yaw, dims, variant={"seed": j + 1})
                for j, (c, x, y, yaw, dims) in enumerate(lay)]
        info = sess.render_frame(FramePlan(f"post{f}", 0.0, T.tolist(), objs, SUN), path,
                                 {"rgba", "index", "shadow_catcher", "lighting"})
        print(f"{path}: region {info['region']}, {info['timings']['render']:.1f} s", flush=True)
    sess.close()


if __name__ == "__main__":
    main()
