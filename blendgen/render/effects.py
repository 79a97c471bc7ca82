"""Only the effects a scene calls for: pure, bpy-free decisions from the plan, the camera
and the job, each with the reason that goes to the manifest.

All pixel quantities here are in the pinhole canvas Blender renders (projection.Canvas).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from blendgen.geometry import Camera, invert_pose
from blendgen.plan import FramePlan, PlacedObject

OUTPUTS = ("rgba", "index", "depth", "shadow_catcher", "lighting")
LIGHTING_PASSES = ("diffuse_direct", "diffuse_indirect", "diffuse_color",
                   "glossy_direct", "glossy_indirect", "glossy_color")
NEAR_M = 0.05
MAX_SHADOW_M = 60.0       # a sun near the horizon casts shadows longer than any useful region
MIN_SUN_ELEVATION = 0.02  # sin(elevation): below this the sun casts no shadow we render
SUN_MARGIN_M = 0.4        # catcher patch beyond footprint and sun shadow (penumbra, contact)
SOFT_MARGIN_M = 1.0       # without a sun: the sky/street-light shadow fades over about this
BLUR_PX = 0.5
REGION_MARGIN_PX = 4      # pixel filter (1.5 px) and rounding
FULL_FRAME_FRACTION = 0.8  # a region this large saves too little to be worth the border logic
# The fixed cost of one more border render (Cycles' render call, denoiser set-up, EXR write and
# read) as a fraction of the frame's pixels: it grows with the frame, 0.07 CPU s = 1200 region
# pixels at 640x360, 0.21 CPU s = 4300 at 1280x720 (benchmarks/render/bench_render.py, docs/render.md).
REGION_OVERHEAD_FRACTION = 0.0045
# On a GPU a render call costs ~0.03 s wall while a pixel costs ~0.7 us: one call is worth
# ~5 % of a 1280x720 frame (H200, OptiX: benchmarks/render/bench_render_gpu.py, docs/render.md).
REGION_OVERHEAD_FRACTION_GPU = 0.05
# Used when a plan carries no lighting estimate: a clear-sky late morning.
DEFAULT_LIGHTING = {
    "sun_direction": [0.35, 0.25, 0.90], "sun_strength": 3.0, "sun_color": [1.0, 0.97, 0.92],
    "sun_angle_deg": 0.53, "sky_color": [0.55, 0.65, 0.85], "sky_strength": 1.0, "sun_visible": True,
}


@dataclass
class Decision:
    value: Any
    reason: str
    extra: dict = field(default_factory=dict)  # e.g. the region's clusters; omitted when empty


@dataclass
class FrameEffects:
    passes: Decision
    objects: Decision            # ids kept (list); culled ids and why in the reason
    motion_blur: Decision        # bool; per-object displacement in the reason
    shadow_catcher: Decision     # bool
    region: Decision             # (x0, y0, x1, y1) canvas pixels, exclusive end, or None = full
    sampling: Decision           # dict of Cycles settings
    skip_render: Decision        # bool: nothing visible, Blender is not called
    blur_px: dict[int, float] = field(default_factory=dict)
    shutter_s: float = 0.0       # the exposure the blur was decided (and is rendered) for

    @property
    def regions(self) -> list[tuple[int, int, int, int]] | None:
        """The boxes to render one by one (None: full frame)."""
        if self.region.value is None:
            return None
        return self.region.extra.get("clusters") or [self.region.value]

    def to_dict(self) -> dict:
        d = {k: asdict(v) for k, v in self.__dict__.items() if isinstance(v, Decision)}
        for v in d.values():
            if not v["extra"]:
                del v["extra"]
        return d


# ---------------------------------------------------------------- passes
def decide_passes(outputs: set[str]) -> Decision:
    unknown = set(outputs) - set(OUTPUTS)
    if unknown:
        raise ValueError(f"unknown render outputs {sorted(unknown)}; expected a subset of {list(OUTPUTS)}")
    keys = [k for k in ("rgba", "index", "depth", "shadow_catcher") if k in outputs]
    if "lighting" in outputs:
        keys += list(LIGHTING_PASSES)
    dropped = [k for k in OUTPUTS if k not in outputs]
    reason = f"outputs {sorted(outputs)} ask for these passes" + (f"; not rendered: {dropped}" if dropped else "")
    return Decision(keys, reason)


# ---------------------------------------------------------------- geometry helpers
def sun_direction(lighting: dict | None) -> np.ndarray | None:
    """Unit vector toward the sun when it casts shadows, else None."""
    if not lighting or not lighting.get("sun_visible", False) or float(lighting.get("sun_strength", 0)) <= 0:
        return None
    d = np.asarray(lighting.get("sun_direction", (0, 0, 1)), dtype=float)
    n = np.linalg.norm(d)
    if not np.isfinite(n) or n < 1e-9:
        return None
    d = d / n
    return d if d[2] > MIN_SUN_ELEVATION else None


def shadow_light_direction(lighting: dict | None) -> np.ndarray | None:
    """Unit vector toward the light whose shadows the ground catches: the visible sun, else
    (night, dusk) the overhead street-light key, whose wide, high source gives the soft
    contact shadow under an object that real street lighting gives, never a long sun shadow."""
    sun = sun_direction(lighting)
    street = (lighting or {}).get("street_light")
    if sun is not None or not street or float(street.get("strength", 0)) <= 0:
        return sun
    d = np.asarray(street.get("direction", (0, 0, 1)), dtype=float)
    n = np.linalg.norm(d)
    return d / n if np.isfinite(n) and n > 1e-9 and d[2] / n > MIN_SUN_ELEVATION else None


# Night and dusk: street lamps beside the road light each object instead of a uniform key.
LAMP_HEIGHT_M = 7.5         # street lamps stand 6-10 m high
LAMP_ALONG_M = (5.0, 14.0)  # one lamp ahead of or behind each object, along its heading ...
LAMP_OUT_M = (2.0, 4.5)     # ... and out to its side of the road (away from the camera's line)
LAMP_RADIUS_M = 0.2         # a lamp head: small, sharp highlights on paint and glass
LAMP_MERGE_M = 8.0          # a lamp this near another one is the same lamp
MAX_LAMPS = 8
LAMP_EGO_LANE_M = 1.2       # an object within this of the camera's line gets its lamp on a random side


def street_lamps(objects, T_world_cam, street: dict | None) -> list[dict]:
    """Night/dusk: point lamps on poles beside the road, one near each object (ahead of or
    behind it, out to its side of the road), in the street key's colour. A lamp's power puts
    the street key's horizontal irradiance (what the overhead key gave every object alike) on
    the top of its object (1 m above the road): objects keep their light level, which post's
    local light matching then sets from the real road at their foot, and gain what a uniform
    key lacks: light falling off along and down the body, a lit side and a dark one, and the
    lamps' highlights. [{"position", "power_w", "color", "radius_m"}] ([] by day)."""
    if not street or float(street.get("strength", 0.0)) <= 0:
        return []
    d = np.asarray(street.get("direction", (0, 0, 1)), dtype=float)
    d = d / max(np.linalg.norm(d), 1e-9)
    E_h = float(street["strength"]) * max(float(d[2]), 0.1)  # the key's horizontal irradiance
    cam = np.asarray(T_world_cam, dtype=float)[:3, 3]
    lamps: list[dict] = []
    for o in sorted(objects, key=lambda o: int(o.id)):
        if o.cls == "person" and (o.variant or {}).get("rides") is not None:
            continue  # a rider is lit by the lamp of what it rides
        rng = np.random.default_rng([int(o.id), 0x1A3B])
        p = np.asarray(o.position, dtype=float)
        h = np.array([np.cos(o.yaw), np.sin(o.yaw), 0.0])
        n = np.array([-h[1], h[0], 0.0])
        lateral = float((p - cam) @ n)
        side = np.sign(lateral) if abs(lateral) > LAMP_EGO_LANE_M else rng.choice((-1.0, 1.0))
        along = rng.uniform(*LAMP_ALONG_M) * rng.choice((-1.0, 1.0))
        out = rng.uniform(*LAMP_OUT_M) + 0.5 * float(o.dims[1])
        pos = p + along * h + side * out * n
        pos[2] = p[2] + LAMP_HEIGHT_M
        if any(np.linalg.norm(pos[:2] - np.asarray(q["position"])[:2]) < LAMP_MERGE_M for q in lamps):
            continue
        top = p + np.array([0.0, 0.0, 1.0])
        v = pos - top
        dist = float(np.linalg.norm(v))
        cos_t = max(float(v[2]) / dist, 0.2)
        lamps.append({"position": [float(x) for x in pos], "power_w": float(E_h * 4 * np.pi * dist ** 2 / cos_t),
                      "color": [float(c) for c in street.get("color", (1, 1, 1))][:3], "radius_m": LAMP_RADIUS_M,
                      "object": int(o.id)})
        if len(lamps) >= MAX_LAMPS:
            break
    return lamps


# The camera car's own low beams: what lights the rears of the vehicles ahead at night.
HEADLIGHT_AHEAD_M = 1.8     # lamps this far ahead of the camera (the hood's front) ...
HEADLIGHT_HEIGHT_M = 0.7    # ... this high above the road ...
HEADLIGHT_HALF_TRACK_M = 0.7  # ... and this far either side of its axis
HEADLIGHT_DOWN_DEG = 1.5    # low beams aim a little down
HEADLIGHT_SPOT_DEG = 60.0
HEADLIGHT_BLEND = 0.4
HEADLIGHT_REF_M = 8.0       # at this distance the beams give a surface facing them the street key's irradiance
HEADLIGHT_FLAT = 0.3        # the beam's height over its width: a low beam's flat top
HEADLIGHT_COLOR = (1.0, 0.95, 0.86)  # warm white


def ego_headlights(T_world_cam, street: dict | None, ground_z: float = 0.0) -> list[dict]:
    """Night/dusk: the camera car's two low beams, spot lights at its front aimed along its
    heading (light falling off with the square of the distance: a car close ahead is bright, one
    far ahead dark). [{"position", "direction", "power_w", "spot_deg", "blend", "color"}]; []
    by day."""
    if not street or float(street.get("strength", 0.0)) <= 0:
        return []
    d = np.asarray(street.get("direction", (0, 0, 1)), dtype=float)
    E_h = float(street["strength"]) * max(float(d[2] / max(np.linalg.norm(d), 1e-9)), 0.1)
    T = np.asarray(T_world_cam, dtype=float)
    fwd = T[:3, 2].copy()
    fwd[2] = 0.0
    if np.linalg.norm(fwd) < 1e-6:
        return []
    fwd /= np.linalg.norm(fwd)
    left = np.array([-fwd[1], fwd[0], 0.0])
    aim = fwd * np.cos(np.radians(HEADLIGHT_DOWN_DEG)) - np.array([0, 0, np.sin(np.radians(HEADLIGHT_DOWN_DEG))])
    power = E_h * 4 * np.pi * HEADLIGHT_REF_M ** 2 / 2  # two lamps
    out = []
    for side in (-1.0, 1.0):
        pos = T[:3, 3] + HEADLIGHT_AHEAD_M * fwd + side * HEADLIGHT_HALF_TRACK_M * left
        pos[2] = ground_z + HEADLIGHT_HEIGHT_M
        out.append({"position": [float(x) for x in pos], "direction": [float(x) for x in aim], "power_w": float(power),
                    "spot_deg": HEADLIGHT_SPOT_DEG, "blend": HEADLIGHT_BLEND, "flat": HEADLIGHT_FLAT,
                    "color": list(HEADLIGHT_COLOR)})
    return out


def shadow_points(corners: np.ndarray, sun_dir: np.ndarray | None, ground_z: float) -> np.ndarray:
    """Where the box corners' shadows fall on the ground plane z = ground_z (along -sun_dir)."""
    if sun_dir is None:
        return np.zeros((0, 3))
    h = corners[:, 2] - ground_z
    length = np.minimum(h / sun_dir[2], MAX_SHADOW_M / max(np.linalg.norm(sun_dir[:2]), 1e-6))
    pts = corners - sun_dir[None, :] * length[:, None]
    pts[:, 2] = ground_z
    return pts


def base_z(obj: PlacedObject) -> float:
    """The ground height under an object: a traffic light's head hangs mount_height_m above it,
    a rider's box starts above_ground_m up (at the pegs or pedals)."""
    hang = obj.variant.get("mount_height_m", 0.0) if obj.cls == "traffic light" else \
        obj.variant.get("above_ground_m", 0.0)
    return float(obj.position[2]) - float(hang)


def object_points(obj: PlacedObject, sun_dir: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """(box corners Nx3, shadow points Nx3) in the world frame."""
    corners = obj.box_corners_world()
    base = base_z(obj)
    if obj.variant.get("pole"):  # a signal head on its own pole: the drawn pole reaches the ground
        foot = corners[::2].copy()
        foot[:, 2] = base
        corners = np.vstack([corners, foot])
    return corners, shadow_points(corners, sun_dir, base)


def _to_cam(T_world_cam, X) -> np.ndarray:
    T = invert_pose(np.asarray(T_world_cam, dtype=float))
    return np.asarray(X, dtype=float) @ T[:3, :3].T + T[:3, 3]


def _frustum_planes(cam: Camera, margin_px: float) -> list[np.ndarray]:
    """Inward normals (camera frame, through the origin) of the 4 side planes, plus margin."""
    x0 = (-0.5 - margin_px - cam.cx) / cam.fx
    x1 = (cam.width - 0.5 + margin_px - cam.cx) / cam.fx
    y0 = (-0.5 - margin_px - cam.cy) / cam.fy
    y1 = (cam.height - 0.5 + margin_px - cam.cy) / cam.fy
    return [np.array([1.0, 0, -x0]), np.array([-1.0, 0, x1]), np.array([0, 1.0, -y0]), np.array([0, -1.0, y1])]


def outside_frustum(cam: Camera, Xc: np.ndarray, margin_px: float = REGION_MARGIN_PX) -> str | None:
    """Why a convex point set (camera frame) cannot be seen, or None if it may be."""
    if len(Xc) == 0:
        return "no points"
    if np.all(Xc[:, 2] < NEAR_M):
        return "behind the camera"
    names = ("left of", "right of", "above", "below")
    for name, n in zip(names, _frustum_planes(cam, margin_px)):
        if np.all(Xc @ n < 0):
            return f"{name} the frame"
    return None


def _project_box(cam: Camera, Xc: np.ndarray) -> tuple[float, float, float, float] | None:
    """Pixel bounds of a convex point set, clipped at the near plane; None if all behind."""
    front = Xc[Xc[:, 2] >= NEAR_M]
    behind = Xc[Xc[:, 2] < NEAR_M]
    if len(front) == 0:
        return None
    pts = [front]
    if len(behind):
        # Points where segments (front, behind) cross the near plane bound the clipped hull.
        a = front[:, None, :]
        b = behind[None, :, :]
        s = (a[..., 2] - NEAR_M) / (a[..., 2] - b[..., 2])
        pts.append((a + s[..., None] * (b - a)).reshape(-1, 3))
    P = np.concatenate(pts)
    u = cam.fx * P[:, 0] / P[:, 2] + cam.cx
    v = cam.fy * P[:, 1] / P[:, 2] + cam.cy
    return float(u.min()), float(v.min()), float(u.max()), float(v.max())


# ---------------------------------------------------------------- culling
def cull_objects(plan: FramePlan, cam: Camera, sun_dir: np.ndarray | None) -> tuple[list[PlacedObject], dict[int, str]]:
    """Objects whose box or shadow may be seen; the others with why they were dropped."""
    kept, culled = [], {}
    for obj in plan.objects:
        corners, shadow = object_points(obj, sun_dir)
        why_obj = outside_frustum(cam, _to_cam(plan.T_world_cam, corners))
        why_sh = outside_frustum(cam, _to_cam(plan.T_world_cam, shadow)) if len(shadow) else "no sun shadow"
        if why_obj is None or why_sh is None:
            kept.append(obj)
        else:
            culled[int(obj.id)] = f"box {why_obj}; shadow: {why_sh}"
    return kept, culled


# ---------------------------------------------------------------- motion blur
SHUTTER_DAY_S = 1.0 / 1000   # a dashcam's auto exposure in daylight: the real frames' cars and poles are sharp
SHUTTER_LOW_LIGHT_S = 1.0 / 120  # dusk, night, or no light estimate


def shutter_for(render, lighting: dict | None) -> float:
    """`render.shutter_s`, or for "auto" the exposure a camera picks in the frame's light: on
    the real freeway video (sunny, ~32 m/s) the real poles beside the road are sharp, where
    1/120 s smeared a virtual cyclist there by 11 px (motion blur is relative to the camera)."""
    if render.shutter_s != "auto":
        return float(render.shutter_s)
    return SHUTTER_DAY_S if (lighting or {}).get("condition") == "day" else SHUTTER_LOW_LIGHT_S


def blur_px(obj: PlacedObject, cam: Camera, T_world_cam, shutter_s: float, cam_velocity=(0.0, 0.0, 0.0)) -> float:
    """Largest image displacement (px) of the box corners during the exposure, relative to the
    camera (moving at `cam_velocity`, world m/s): a car driving with the camera stays sharp."""
    v = np.asarray(obj.velocity, dtype=float) - np.asarray(cam_velocity, dtype=float)
    if shutter_s <= 0 or not np.any(v):
        return 0.0
    corners = obj.box_corners_world()
    a = _to_cam(T_world_cam, corners - v * shutter_s / 2)
    b = _to_cam(T_world_cam, corners + v * shutter_s / 2)
    ok = (a[:, 2] > NEAR_M) & (b[:, 2] > NEAR_M)
    if not np.any(ok):
        return 0.0
    a, b = a[ok], b[ok]
    du = cam.fx * (a[:, 0] / a[:, 2] - b[:, 0] / b[:, 2])
    dv = cam.fy * (a[:, 1] / a[:, 2] - b[:, 1] / b[:, 2])
    return float(np.max(np.hypot(du, dv)))


def decide_motion_blur(objects, cam: Camera, T_world_cam, shutter_s: float,
                       mode: str, cam_velocity=(0.0, 0.0, 0.0)) -> tuple[Decision, dict[int, float]]:
    px = {int(o.id): round(blur_px(o, cam, T_world_cam, shutter_s, cam_velocity), 3) for o in objects}
    worst = max(px.values(), default=0.0)
    if mode == "off":
        return Decision(False, "render.motion_blur is off"), px
    if mode == "on":
        on = worst > 0
        return Decision(on, "render.motion_blur is on" + ("" if on else ", but nothing moves")), px
    if worst > BLUR_PX:
        movers = {i: p for i, p in px.items() if p > BLUR_PX}
        return Decision(True, f"objects {sorted(movers)} move up to {worst:.2f} px > {BLUR_PX} px "
                              f"during the {shutter_s * 1000:.1f} ms shutter"), px
    return Decision(False, f"largest motion during the shutter is {worst:.2f} px <= {BLUR_PX} px"), px


# ---------------------------------------------------------------- shadow catcher
def decide_shadow_catcher(lighting: dict | None, outputs: set[str]) -> Decision:
    if "shadow_catcher" not in outputs:
        return Decision(False, "shadow_catcher not among the outputs")
    if not lighting:
        return Decision(False, "no lighting estimate for this frame: no sun, no cast shadows")
    if sun_direction(lighting) is not None:
        return Decision(True, "the sun is visible: ground catches the objects' shadows")
    # Without a sun an object still darkens the ground under it (the sky or the street light it
    # hides): without that contact shadow vehicles float on overcast and night photos.
    if shadow_light_direction(lighting) is not None:
        return Decision(True, f"{lighting.get('condition', 'night')}: the ground catches the soft contact "
                              "shadows of the overhead street-light key and the sky (no sun shadow)")
    if float(lighting.get("sky_strength", 0)) > 0:
        return Decision(True, "no sun shadow: the ground under each object catches the soft shadow of the sky")
    return Decision(False, "no light source to cast a shadow")


def catcher_patches(objects, sun_dir: np.ndarray | None, margin_m: float | None = None) -> list[np.ndarray]:
    """Ground polygons (each Kx3, counter-clockwise, at the object's base height) that can
    receive an object's shadow: the convex hull of its footprint and its shadow, grown by
    `margin_m` (contact shadows, soft penumbra; default SUN_MARGIN_M, or SOFT_MARGIN_M without
    a sun, where the sky shadow fades out slowly). Catching shadows only there keeps the
    expensive shadow-catcher pixels to the few that can hold a shadow."""
    import cv2

    margin_m = margin_m if margin_m is not None else SUN_MARGIN_M if sun_dir is not None else SOFT_MARGIN_M
    ring = margin_m * np.stack([np.cos(np.linspace(0, 2 * np.pi, 8, endpoint=False)),
                                np.sin(np.linspace(0, 2 * np.pi, 8, endpoint=False))], axis=1)
    hulls = []
    for obj in objects:
        corners, shadow = object_points(obj, sun_dir)
        pts = np.concatenate([corners[:, :2], shadow[:, :2]]) if len(shadow) else corners[:, :2]
        # Penumbra grows with distance from the caster: widen the margin with the height.
        grown = (pts[:, None, :] + ring[None] * (1.0 + 0.1 * float(obj.dims[2]))).reshape(-1, 2)
        hulls.append((cv2.convexHull(grown.astype(np.float32)).reshape(-1, 2), base_z(obj)))
    out = []
    for hull, z in _merge_overlapping(hulls):
        hull = hull.astype(float)
        if len(hull) >= 3:
            area = 0.5 * np.sum(hull[:, 0] * np.roll(hull[:, 1], -1) - np.roll(hull[:, 0], -1) * hull[:, 1])
            if area < 0:
                hull = hull[::-1]
            out.append(np.c_[hull, np.full(len(hull), z)])
    return out


def catcher_lift_m(poly: np.ndarray) -> float:
    """How far above the ground a catcher patch lies: 0.2 mm, or 8 float32 steps of
    coordinates far from the origin. Coplanar with the ground's faces the objects' pixels
    were 5 dB off the reference; at 2 mm the sharp shadow edges moved by a fifth of a pixel
    at 14 m (the shadow pixels 1.3 dB off, docs/render.md)."""
    return max(2e-4, 1e-6 * float(np.abs(poly).max()))


def _merge_overlapping(hulls: list[tuple[np.ndarray, float]], dz_m: float = 0.05) -> list[tuple[np.ndarray, float]]:
    """Replace overlapping patches at (nearly) one height by the convex hull of both, until
    none overlap: coplanar catcher faces over the same ground put bands of false shadow on
    the road where a person's patch met a bicycle's or the margins of neighbours met
    (tests/test_render_bpy.py, docs/render.md)."""
    import cv2

    out: list[tuple[np.ndarray, float]] = []  # pairwise disjoint
    for hull, z in hulls:
        while True:  # fold in every kept patch the (growing) hull overlaps
            k = next((k for k, (h, zk) in enumerate(out)
                      if abs(zk - z) <= dz_m and cv2.intersectConvexConvex(h, hull)[0] > 0), None)
            if k is None:
                break
            h, zk = out.pop(k)
            hull, z = cv2.convexHull(np.concatenate([h, hull])).reshape(-1, 2), max(z, zk)
        out.append((hull, z))
    return out


# ---------------------------------------------------------------- region
def decide_region(plan: FramePlan, objects, cam: Camera, sun_dir: np.ndarray | None,
                  enabled: bool, extra_margin_px: float = 0.0, gpu: bool = False) -> Decision:
    """Border render boxes from the projected boxes and shadows of the kept objects.

    Value: the union box (x0, y0, x1, y1) or None (full frame); ``extra["clusters"]``: the
    boxes rendered one by one (cluster_boxes)."""
    W, H = cam.width, cam.height
    if not enabled:
        return Decision(None, "render.region is off: full frame")
    if not objects:
        return Decision(None, "no objects")
    m = REGION_MARGIN_PX + extra_margin_px
    per_object = []
    for obj in objects:
        boxes = []
        corners, shadow = object_points(obj, sun_dir)
        for pts in (corners, shadow):
            if len(pts) == 0:
                continue
            Xc = _to_cam(plan.T_world_cam, pts)
            if outside_frustum(cam, Xc) is not None:
                continue
            b = _project_box(cam, Xc)
            if b is not None:
                boxes.append(b)
        if boxes:
            B = np.array(boxes)
            box = (int(np.clip(np.floor(B[:, 0].min() - m), 0, W)),
                   int(np.clip(np.floor(B[:, 1].min() - m), 0, H)),
                   int(np.clip(np.ceil(B[:, 2].max() + m + 1), 0, W)),
                   int(np.clip(np.ceil(B[:, 3].max() + m + 1), 0, H)))
            if box[2] > box[0] and box[3] > box[1]:
                per_object.append(box)
    if not per_object:
        return Decision(None, "no object or shadow projects into the frame")
    B = np.array(per_object)
    x0, y0, x1, y1 = int(B[:, 0].min()), int(B[:, 1].min()), int(B[:, 2].max()), int(B[:, 3].max())
    clusters = cluster_boxes(per_object, (REGION_OVERHEAD_FRACTION_GPU if gpu else REGION_OVERHEAD_FRACTION) * W * H)
    area = sum((c[2] - c[0]) * (c[3] - c[1]) for c in clusters)
    frac = area / float(W * H)
    what = "objects and their shadows" if sun_dir is not None else "objects (no sun shadow)"
    if frac >= FULL_FRAME_FRACTION:
        return Decision(None, f"{what} cover {frac:.0%} of the frame: full frame")
    return Decision((x0, y0, x1, y1), f"{what} project into {frac:.1%} of the frame, rendered as "
                    f"{len(clusters)} region{'s' if len(clusters) > 1 else ''}",
                    {"clusters": [list(c) for c in clusters]})


def cluster_boxes(boxes, overhead_px: float) -> list[tuple[int, int, int, int]]:
    """Group pixel boxes into the render regions that cost least: greedily merge the pair
    whose union costs less than the two apart (cost = area + ``overhead_px``, the fixed cost
    of one more render), the largest saving first. Two objects side by side share one region;
    two at opposite edges get one each, not the empty frame between them."""
    over = overhead_px
    bs = [tuple(int(v) for v in b) for b in boxes]

    def cost(b):
        return (b[2] - b[0]) * (b[3] - b[1]) + over

    while len(bs) > 1:
        best, pair = 0.0, None
        for i in range(len(bs)):
            for j in range(i + 1, len(bs)):
                a, b = bs[i], bs[j]
                u = (min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3]))
                saving = cost(a) + cost(b) - cost(u)
                if saving >= best:  # ties merge: one render is simpler than two
                    best, pair = saving, (i, j, u)
        if pair is None:
            break
        i, j, u = pair
        bs = [b for k, b in enumerate(bs) if k not in (i, j)] + [u]
    return sorted(bs)


def border_fractions(region, width: int, height: int) -> tuple[float, float, float, float]:
    """Pixel box (top-left origin) -> Blender border min_x, max_x, min_y, max_y (bottom-left)."""
    x0, y0, x1, y1 = region
    # Blender truncates border * size to whole pixels: nudge by 1e-4 px so that float
    # rounding cannot lose a pixel row or column.
    e = 1e-4
    return (x0 + e) / width, (x1 + e) / width, (height - y1 + e) / height, (height - y0 + e) / height


# ---------------------------------------------------------------- sampling
def decide_sampling(render, passes: list[str]) -> Decision:
    """Cycles sampling and light paths from the job's quality settings."""
    mb = int(render.max_bounces)
    s = {
        "samples": int(render.samples),
        "adaptive": render.adaptive_threshold > 0 and render.samples >= 16,
        "adaptive_threshold": float(render.adaptive_threshold),
        "denoise": bool(render.denoise) and "rgba" in passes,
        "max_bounces": mb,
        # Diffuse light beyond 2-3 bounces is invisible on vehicles outdoors; glass needs transmission.
        "diffuse_bounces": min(mb, 2),
        "glossy_bounces": min(mb, 2),
        "transmission_bounces": min(mb, 4),
        "transparent_bounces": min(max(mb, 2), 8),
        "volume_bounces": 0,
        "caustics": False,
        "clamp_indirect": 10.0,
    }
    why = [f"{s['samples']} samples from render.samples",
           f"adaptive sampling {'on (threshold %g)' % s['adaptive_threshold'] if s['adaptive'] else 'off'}",
           f"denoise {'on' if s['denoise'] else 'off'}" + ("" if "rgba" in passes or not render.denoise
                                                          else " (no rgba output to denoise)"),
           f"bounces: total {mb}, diffuse {s['diffuse_bounces']}, glossy {s['glossy_bounces']}, "
           f"transmission {s['transmission_bounces']}, no volumes or caustics"]
    return Decision(s, "; ".join(why))


# ---------------------------------------------------------------- everything
def check_plan(plan: FramePlan) -> None:
    """ValueError naming the field when a plan cannot be rendered (NaN poses, bad sizes)."""
    T = np.asarray(plan.T_world_cam, dtype=float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"T_world_cam: expected a finite 4x4 matrix, got shape {T.shape}"
                         + ("" if T.shape != (4, 4) else " with non-finite values"))
    if abs(np.linalg.det(T[:3, :3]) - 1.0) > 1e-3:
        raise ValueError("T_world_cam: the rotation part is not a rotation (det != 1)")
    for o in plan.objects:
        if not (np.all(np.isfinite(o.position)) and np.isfinite(o.yaw) and np.all(np.isfinite(o.velocity))):
            raise ValueError(f"object {o.id}: position, yaw and velocity must be finite")
        if not all(np.isfinite(d) and d > 0 for d in o.dims):
            raise ValueError(f"object {o.id}: dims must be positive, got {tuple(o.dims)}")
    _check_numbers(plan.lighting or {}, "lighting")


def _check_numbers(d: dict, where: str) -> None:
    """Every number in a (nested) lighting dict is finite; flags, names and absent parts pass."""
    for k, v in d.items():
        if isinstance(v, dict):
            _check_numbers(v, f"{where}.{k}")
            continue
        vals = np.atleast_1d(np.asarray(v, dtype=float)) if not isinstance(v, (bool, str, type(None))) else np.zeros(1)
        if not np.all(np.isfinite(vals)):
            raise ValueError(f"{where}.{k}: expected finite numbers, got {v!r}")


def decide_effects(plan: FramePlan, cam: Camera, render, outputs: set[str], gpu: bool = False) -> FrameEffects:
    """All per-frame decisions. `cam` is the pinhole canvas that Blender renders; `gpu`: Cycles
    renders on a GPU (a render call costs more there, relative to a pixel)."""
    check_plan(plan)
    passes = decide_passes(set(outputs))
    catcher = decide_shadow_catcher(plan.lighting, set(outputs))
    # Shadows matter for culling/region only when they are rendered.
    sun = shadow_light_direction(plan.lighting) if catcher.value or "rgba" in outputs else None
    kept, culled = cull_objects(plan, cam, sun)
    reason = f"{len(kept)} of {len(plan.objects)} objects may be seen"
    if culled:
        reason += "; culled: " + "; ".join(f"{i}: {w}" for i, w in culled.items())
    objects = Decision([int(o.id) for o in kept], reason)
    shutter = shutter_for(render, plan.lighting)
    blur, px = decide_motion_blur(kept, cam, plan.T_world_cam, shutter, render.motion_blur, plan.camera_velocity)
    margin = max(px.values(), default=0.0) if blur.value else 0.0
    region = decide_region(plan, kept, cam, sun, bool(render.region), extra_margin_px=margin, gpu=gpu)
    sampling = decide_sampling(render, passes.value)
    if not kept:
        skip = Decision(True, "no object or shadow in the view: empty passes written without Blender")
    else:
        skip = Decision(False, f"{len(kept)} objects to render")
    return FrameEffects(passes, objects, blur, catcher, region, sampling, skip, px, shutter)
