"""What a real background frame allows the planner (bpy-free): its real road users, road,
bands and hood, read from the analysis stage's files.

`RealScene.reject(...)` says why a virtual object may not stand somewhere in a frame, or
None: inside a real road user's footprint; behind a real one in the image (there is no
pixel-exact mask of the real object to put in front of it); touching the hood; a
vehicle's wheel off the estimated road, or its footprint across the frame's solid right edge
line (a freeway's shoulder; not for bicycles and parked motorcycles, which keep to the edge); a
pedestrian outside the bands beside the road or in the oncoming lane beyond a centre line
(unless crossing); a traffic light's pole on the road. A virtual object in front of a real one
is allowed: it covers it. `lane_centres` puts vehicles in the real lanes between the frame's
painted lines.
"""

from __future__ import annotations

import cv2
import numpy as np

from blendgen.frame_analysis import BAND, ROAD, FrameAnalysis
from blendgen.geom2d import convex_overlap
from blendgen.geometry import Camera
from blendgen.lane_geometry import kept_lines, lane_centres

WHEELED = ("car", "bus", "truck", "motorcycle", "bicycle")
ROAD_EDGE = -1             # sample_ground: road pixels within EDGE_PX of its left or right edge
EDGE_PX = 24
FOOTPRINT_MARGIN_M = 0.3
EDGE_LINE_CLEAR_M = 0.1    # a vehicle's footprint keeps this far left of a solid right edge line
MIN_IMAGE_OVERLAP = 0.05   # of the virtual object's box: less is a touch, not "behind"
ONCOMING_LANE_M = 2.7      # beyond a centre line the oncoming lane is at least this wide (9 ft)


class RealFrame:
    def __init__(self, fa: FrameAnalysis, road_mask: np.ndarray | None, hood_mask: np.ndarray | None):
        self.fa = fa
        self.road = road_mask
        self.hood = hood_mask
        self.footprints = [(o, np.asarray(o.footprint, float)) for o in fa.real_objects if o.footprint]
        self.boxes = [(o, np.asarray(o.box, float)) for o in fa.real_objects]

    def decision(self, what: str) -> str:
        """The analysis' reason for `what` (its decisions), or ''."""
        return next((str(d.get("reason", "")) for d in self.fa.decisions if d.get("what") == what), "")


class RealScene:
    """Per frame index k of the plan: the real frame's constraints."""

    def __init__(self, frames: list[RealFrame | None], camera: Camera):
        self.frames = frames
        self.camera = camera
        self._has: dict[tuple[int, int], bool] = {}  # the planner asks on every spawn
        self._kept: dict[tuple[int, float], list] = {}

    def _pixels(self, rf: RealFrame, T, pts3: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Analysis-resolution pixels of world points and whether each lies inside the image."""
        uv, front = self.camera.project_world(T, pts3)
        uv = uv * [rf.fa.width / self.camera.width, rf.fa.height / self.camera.height]
        inside = front & (uv[:, 0] >= 0) & (uv[:, 1] >= 0) & (uv[:, 0] < rf.fa.width) & (uv[:, 1] < rf.fa.height)
        return uv, inside

    def reject(self, k: int, T, cls: str, corners: np.ndarray, z: float, height: float, *,
               crossing: bool = False, kerb: bool = False) -> str | None:
        """Why the object may not stand there in frame k, or None. `kerb`: a two-wheeler that
        keeps to the road's edge (a bicycle, a parked motorcycle) may cross its edge line."""
        rf = self.frames[k] if k < len(self.frames) else None
        if rf is None:
            return None
        T = np.asarray(T, float)
        lat = corners[:, 1] - float(T[1, 3])  # the ground-plane twin's road runs along +x
        if (cls in WHEELED and not kerb and rf.fa.edge_line_m is not None
                and float(np.min(lat)) < rf.fa.edge_line_m + EDGE_LINE_CLEAR_M):
            return "across the road's solid right edge line (the shoulder)"
        cl = rf.fa.centre_line_m
        if cls == "person" and not crossing and cl is not None and float(np.min(lat)) < cl + ONCOMING_LANE_M \
                and float(np.max(lat)) > cl:
            # the BDD night street's dark far lane passed as pavement beside the lit road
            return f"in the oncoming lane (within {ONCOMING_LANE_M:g} m beyond the centre line)"
        for o, fp in self.footprints_near(rf, corners):
            if convex_overlap(corners, fp, FOOTPRINT_MARGIN_M):
                return f"inside the footprint of a real {o.cls}"
        box3 = np.concatenate([np.column_stack([corners, np.full(4, z)]),
                               np.column_stack([corners, np.full(4, z + height)])])
        uv, inside = self._pixels(rf, T, box3)
        if not inside.any():
            return None
        lo, hi = uv.min(0), uv.max(0)
        area = max(float(np.prod(hi - lo)), 1e-6)
        near = float(np.min(np.linalg.norm(corners - T[:2, 3], axis=1)))
        for o, (x, y, w, h) in rf.boxes:
            ix = max(0.0, min(hi[0], x + w) - max(lo[0], x))
            iy = max(0.0, min(hi[1], y + h) - max(lo[1], y))
            if ix * iy > MIN_IMAGE_OVERLAP * area and (o.distance_m is None or near >= o.distance_m):
                return f"behind a real {o.cls} (it would be drawn over it)"
        contact, cin = self._pixels(rf, T, np.column_stack([_inset(corners), np.full(4, z)]))
        ci = np.clip(np.round(contact).astype(int), 0, [rf.fa.width - 1, rf.fa.height - 1])
        if rf.hood is not None and (rf.hood[ci[cin, 1], ci[cin, 0]]).any():
            return "on the ego vehicle's hood"
        if rf.road is None:
            return None
        vals = rf.road[ci[cin, 1], ci[cin, 0]]
        if cls == "traffic light" and (vals == ROAD).any():
            return "its pole would stand on the estimated road"
        if cls in WHEELED and (vals != ROAD).any():
            return "a wheel off the estimated road"
        if cls == "person" and not crossing and (vals != BAND).all():
            return "not on the walkable band beside the road"
        return None

    def closed(self, k: int) -> str | None:
        """Why no new object of any class may be placed in frame k, or None. Every class stands
        on the frame's road or beside it: a frame without a road region (all hood, no free
        ground, a black frame) takes none, and neither does a frame whose camera is too
        uncertain for any distance of the job (`max_distance`)."""
        rf = self.frames[k] if k < len(self.frames) else None
        if rf is None:
            return None
        if rf.road is None:
            why = rf.decision("road") or "no road region"
            return f"no road region in this frame ({why})"
        return None

    def max_distance(self, k: int) -> tuple[float, str]:
        """How far from the camera objects may stand in frame k (inf: no limit) and why: the
        analysis' `placement_max_m`, from the camera's pitch, roll and height uncertainty."""
        rf = self.frames[k] if k < len(self.frames) else None
        lim = None if rf is None else rf.fa.placement_max_m
        if lim is None:
            return float("inf"), ""
        return float(lim), rf.decision("placement_max_m")

    def oncoming(self, k: int, T, xy) -> bool:
        """Whether traffic at ground point `xy` comes towards the camera in frame k: beyond the
        frame's centre line (the analysis' `centre_line_m`, left of the camera at pose T)."""
        cl = self.centre_line(k)
        # the ground-plane twin's road runs along +x: lateral offset = world y from the camera
        return cl is not None and float(xy[1]) - float(np.asarray(T, float)[1, 3]) > cl

    def lane_centres(self, k: int, T, x_world: float, lane_width_m: float) -> dict[int, float] | None:
        """World y of the centres of frame k's real lanes at world x_world, by lane (0 the
        camera's, +1 the next on its left, -1 on its right), from the painted lines the
        analysis found (`analysis.lanes`), or None where they bound no ego lane."""
        rf = self.frames[k] if k < len(self.frames) else None
        T = np.asarray(T, float)
        if rf is not None and (k, lane_width_m) not in self._kept:  # per frame: the planner asks many times
            self._kept[k, lane_width_m] = kept_lines(rf.fa.lane_lines, lane_width_m)
        centres = None if rf is None else lane_centres(rf.fa.lane_lines, x_world - float(T[0, 3]), lane_width_m,
                                                       kept=self._kept[k, lane_width_m])
        # the ground-plane twin's road runs along +x
        return None if centres is None else {n: float(T[1, 3]) + c for n, c in centres.items()}

    def centre_line(self, k: int) -> float | None:
        rf = self.frames[k] if k < len(self.frames) else None
        return None if rf is None else rf.fa.centre_line_m

    def has(self, k: int, value: int) -> bool:
        """Whether frame k has road (ROAD) or band (BAND) pixels."""
        if (k, value) not in self._has:
            rf = self.frames[k] if k < len(self.frames) else None
            self._has[k, value] = rf is not None and rf.road is not None and bool((rf.road[::4, ::4] == value).any())
        return self._has[k, value]

    def kerb_side(self, k: int, T, xy: np.ndarray) -> np.ndarray:
        """Whether ground points (N, 2) lie on their traffic's kerb side: right of the camera,
        or beyond frame k's centre line (the oncoming traffic's right). A road's left edge with
        all traffic running the ego's way is a divided highway's median or a one-way street's
        far side: no place for a cyclist or a parked motorcycle."""
        lat = np.asarray(xy, float)[:, 1] - float(np.asarray(T, float)[1, 3])
        cl = self.centre_line(k)
        return (lat < 0) | (lat > cl) if cl is not None else lat < 0

    def sample_ground(self, k: int, value: int, T, rng: np.random.Generator, d0: float, d1: float,
                      keep=None) -> np.ndarray | None:
        """A ground point (x, y) on frame k's road or band between d0 and d1 metres away (and,
        with `keep`, one of the points (N, 2) for which keep(points) is True)."""
        from blendgen.ground import to_ground

        rf = self.frames[k] if k < len(self.frames) else None
        if rf is None or rf.road is None:  # nothing estimated to stand on (RealScene.closed says why)
            return None
        if value == ROAD_EDGE:
            road = rf.road == ROAD
            off = cv2.dilate((~road).astype(np.uint8), np.ones((1, 2 * EDGE_PX + 1), np.uint8)) > 0
            v, u = np.nonzero((road & off)[::4, ::4])
        else:
            v, u = np.nonzero(rf.road[::4, ::4] == value)
        if len(u) == 0:
            return None
        pick = rng.choice(len(u), size=min(len(u), 64), replace=False)
        cam = self.camera.scaled(rf.fa.width, rf.fa.height)
        T = np.asarray(T, float)
        g = to_ground(cam, T, np.column_stack([u[pick] * 4 + 2, v[pick] * 4 + 2]))
        d = np.linalg.norm(g - T[:2, 3], axis=1)
        good = np.isfinite(d) & (d >= d0) & (d <= d1)
        if keep is not None:
            good[good] = keep(g[good])
        ok = np.flatnonzero(good)
        return None if len(ok) == 0 else g[ok[0]]

    @staticmethod
    def footprints_near(rf: RealFrame, corners: np.ndarray):
        c = corners.mean(0)
        r = float(np.max(np.linalg.norm(corners - c, axis=1)))
        for o, fp in rf.footprints:
            if np.linalg.norm(fp.mean(0) - c) < r + float(np.max(np.linalg.norm(fp - fp.mean(0), axis=1))) + 1:
                yield o, fp

    def covered(self, k: int, T, corners: np.ndarray, z: float, height: float) -> list[dict]:
        """The real boxes the object's projected box overlaps (it stands in front of them)."""
        rf = self.frames[k] if k < len(self.frames) else None
        if rf is None:
            return []
        box3 = np.concatenate([np.column_stack([corners, np.full(4, z)]),
                               np.column_stack([corners, np.full(4, z + height)])])
        uv, _ = self._pixels(rf, np.asarray(T, float), box3)
        lo, hi = uv.min(0), uv.max(0)
        return [{"cls": o.cls, "box": o.box} for o, (x, y, w, h) in rf.boxes
                if min(hi[0], x + w) > max(lo[0], x) and min(hi[1], y + h) > max(lo[1], y)]


def _inset(corners: np.ndarray, f: float = 0.15) -> np.ndarray:
    """Approximate wheel contact points: the footprint's corners pulled toward its centre."""
    c = corners.mean(0)
    return c + (corners - c) * (1 - f)


def load_real_scene(analysis_dir, frame_ids: list[str], camera: Camera) -> RealScene:
    """The analysis stage's files for `frame_ids` (a frame without a file gets None)."""
    from blendgen.frame_analysis import hood_mask, read_analysis, read_road_mask

    frames = []
    for fid in frame_ids:
        fa = read_analysis(analysis_dir, fid)
        if fa is None:
            frames.append(None)
            continue
        frames.append(RealFrame(fa, read_road_mask(analysis_dir, fa), hood_mask(fa.hood, fa.width, fa.height)))
    return RealScene(frames, camera)
