"""Road-aware scene planning (bpy-free): which objects, where, facing where, in which state.

Each object is a *track*: at spawn time its whole trajectory over the remaining frames is
simulated (vehicles along their lane, bicycles at the road edge, pedestrians along the
sidewalk or across a crosswalk, traffic lights fixed at an intersection slot), then checked
frame by frame against every other track, the ego vehicle (with a headway margin) and the
twin's structures. A candidate that conflicts anywhere is rejected, so accepted tracks never
overlap and never need to be repaired later; ids persist for the track's lifetime.

A frame's plan holds the tracks that are visible in it: box fully in front of the camera,
centre distance within `inject.distance_m`, at least half of the projected box inside the
image and its larger side >= `inject.min_projected_px`, and the line of sight not crossing a
building. New tracks are spawned (visible at their first frame) until the frame holds the
target count drawn from `inject.objects_per_frame`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from blendgen.frame_analysis import BAND, ROAD
from blendgen.geom2d import convex_overlap, point_in_convex, wrap_angle
from blendgen.geometry import Camera, yaw_of_camera
from blendgen.plan import SCENERY_ID, FramePlan, PlacedObject
from blendgen.scene.catalog import SPEED, sample_variant
from blendgen.scene.real_scene import ROAD_EDGE
from blendgen.scene.riders import split_rider
from blendgen.twin.model import Twin

# The ego vehicle's footprint relative to the camera (dashcam behind the windscreen).
EGO_LENGTH, EGO_WIDTH = 4.6, 1.85
EGO_FRONT_OF_CAM = 1.8
EGO_HEADWAY_S, EGO_HEADWAY_MIN_M = 1.0, 2.0
CLEARANCE_M = 0.25        # spawn-time clearance between object footprints
MAX_TRACK_RANGE_M = 90.0  # a track ends once this far from the camera
SPAWN_TRIES = 40
TARGET_PERIOD_S = 3.0     # how often the per-frame object target is redrawn
SCENARIO_PERIOD_S = 8.0   # a scenario whose actors are gone is re-staged after this
SCENARIO_RETRY_S = 1.0
SIGNAL_CYCLE = (("green", 12.0), ("amber", 3.0), ("red", 15.0))
VEHICLES = ("car", "bus", "truck", "motorcycle")
LANE_SMOOTH_S = 0.5         # a video's vehicles follow their painted lane, smoothed over this (Gaussian sigma)
LANE_BORROW_FRAMES = 30     # a video track born without lines takes the nearest of this many frames' lanes
POLE_OFF_ROAD_M = (0.8, 2.0)  # a ground-plane signal pole stands this far beyond the road edge
FLOW_SPEED = (0.85, 1.15)  # real video: a vehicle's speed as a share of the ego's (the traffic it drives in)
FLOW_MIN_EGO_MPS = 3.0     # below this the ego crawls or stands: class speeds
# real video: the ego this fast is on a motorway: 80 km/h on a divided road (no centre line), 100 km/h on any
MOTORWAY_DIVIDED_MPS, MOTORWAY_MPS = 22.0, 28.0
MOTORWAY_CLOSED = ("bicycle", "person", "traffic light")  # none of them on a motorway
SAME_CLASS_TRIES = 8       # places tried for a drawn object before it is given up
PACKING_ORDER = ("bus", "truck", "car", "motorcycle", "bicycle", "person", "traffic light")  # largest first


@dataclass
class Track:
    id: int
    cls: str
    variant: dict
    dims: tuple[float, float, float]
    k0: int
    xy: np.ndarray      # (n, 2) positions for frames k0 .. k0+n-1
    z: np.ndarray       # (n,)
    yaw: np.ndarray     # (n,)
    scenario: str | None = None
    states: list | None = None
    rider_id: int = 0   # a ridden two-wheeler's rider is its own instance (blendgen.scene.riders)
    pitch: np.ndarray | None = None  # (n,) the road's slope under a wheeled object (maps with relief)
    roll: np.ndarray | None = None
    corners: np.ndarray = field(init=False)  # (n, 4, 2) footprints
    radius: float = field(init=False)

    def __post_init__(self):
        n = len(self.xy)
        self.pitch = np.zeros(n) if self.pitch is None else np.asarray(self.pitch, float)[:n]
        self.roll = np.zeros(n) if self.roll is None else np.asarray(self.roll, float)[:n]
        self.corners = footprints(self.xy, self.yaw, self.dims[0], self.dims[1])
        self.radius = 0.5 * math.hypot(self.dims[0], self.dims[1])

    @property
    def k1(self) -> int:
        return self.k0 + len(self.xy)

    def velocity(self, i: int, times: np.ndarray) -> tuple[float, float, float]:
        n = len(self.xy)
        if n < 2:
            return (0.0, 0.0, 0.0)
        a, b = (i, i + 1) if i + 1 < n else (i - 1, i)
        dt = times[self.k0 + b] - times[self.k0 + a]
        v = (self.xy[b] - self.xy[a]) / max(dt, 1e-6)
        return (float(v[0]), float(v[1]), 0.0)


def footprints(xy: np.ndarray, yaw: np.ndarray, length: float, width: float) -> np.ndarray:
    """(n, 4, 2) corners of oriented rectangles; length/width may be per-row arrays."""
    c, s = np.cos(yaw), np.sin(yaw)
    hl = np.broadcast_to(np.asarray(length, float) / 2, c.shape)[:, None] * np.array([1, -1, -1, 1])
    hw = np.broadcast_to(np.asarray(width, float) / 2, c.shape)[:, None] * np.array([1, 1, -1, -1])
    x = c[:, None] * hl - s[:, None] * hw
    y = s[:, None] * hl + c[:, None] * hw
    return np.stack([x, y], axis=2) + xy[:, None, :]


class _Ego:
    """The recording vehicle per frame: camera position, heading, speed and footprints."""

    def __init__(self, poses, twin: Twin):
        self.T = [np.asarray(T, dtype=float) for _, _, T in poses]
        self.t = np.array([float(t) for _, t, _ in poses])
        self.cam = np.array([T[:3, 3] for T in self.T])
        self.yaw = np.array([yaw_of_camera(T[:3, :3]) for T in self.T])
        h = np.stack([np.cos(self.yaw), np.sin(self.yaw)], axis=1)
        self.heading = h
        dt = np.diff(self.t)
        v = np.diff(self.cam, axis=0) / np.maximum(dt, 1e-6)[:, None] if len(dt) else np.zeros((0, 3))
        self.vel = np.concatenate([v, v[-1:]]) if len(v) else np.zeros((1, 3))  # forward differences, world m/s
        self.speed = np.linalg.norm(self.vel[:, :2], axis=1)
        centre = self.cam[:, :2] + h * (EGO_FRONT_OF_CAM - EGO_LENGTH / 2)
        self.box = footprints(centre, self.yaw, EGO_LENGTH, EGO_WIDTH)
        # the box swept forward by the headway: plain traffic keeps out of it
        ahead = np.maximum(EGO_HEADWAY_MIN_M, self.speed * EGO_HEADWAY_S)
        self.safe_box = footprints(centre + h * (ahead / 2)[:, None], self.yaw, EGO_LENGTH + ahead,
                                   EGO_WIDTH + 0.3)
        self.lane = [twin.lane_at(p[0], p[1], heading=y) for p, y in zip(self.cam[:, :2], self.yaw)]

    def velocity(self, k: int, sequences: bool) -> tuple[float, float, float]:
        """The camera's velocity at frame k (world m/s) when objects move over frames too; zero
        for unrelated stills, whose objects carry no velocity either."""
        return tuple(float(c) for c in self.vel[k]) if sequences else (0.0, 0.0, 0.0)


class Planner:
    def __init__(self, twin: Twin, camera: Camera, poses, inject, seed: int, *, assets=None, real=None):
        self.twin, self.camera, self.inject = twin, camera, inject
        self.assets = assets  # blendgen.job.assets.AssetSampler or None
        self.real = real  # scene.real_scene.RealScene: the real frames' road users, road and hood
        self.reason = ""  # why the last candidate was rejected (for the manifest)
        self.rng = np.random.default_rng(seed)
        # library draws have their own stream: a job with a library plans the procedural
        # objects' draws as the same job without one (the realism bench pairs them)
        self.asset_rng = np.random.default_rng([seed, 0xA55E7])
        self.poses = list(poses)
        self.ego = _Ego(self.poses, twin)
        self.times = self.ego.t
        self.K = len(self.poses)
        self.n_plan = self.K  # frames planned (a plan window's later frames only carry its tracks on)
        self.tracks: list[Track] = []
        self.next_id = 1
        classes = {c: w for c, w in inject.classes.items() if w > 0}
        self.classes = list(classes)
        self.weights = np.array([classes[c] for c in self.classes], dtype=float)
        self.weights /= self.weights.sum() if self.weights.sum() > 0 else 1.0
        self.d0, self.d1 = inject.distance_m
        self.hfov = 2 * math.atan(camera.width / 2 / camera.fx)
        self._buildings = [i for i, s in enumerate(twin.structures) if s.kind == "building"]

    # ------------------------------------------------------------ visibility
    def visible(self, tr: Track, k: int) -> bool:
        i = k - tr.k0
        L, W, H = tr.dims
        z0 = tr.z[i]
        corners = np.concatenate([np.column_stack([tr.corners[i], np.full(4, z0)]),
                                  np.column_stack([tr.corners[i], np.full(4, z0 + H)])])
        T = self.ego.T[k]
        centre = np.array([*tr.xy[i], z0 + H / 2])
        dist = float(np.linalg.norm(centre - T[:3, 3]))
        if not self.d0 <= dist <= self.d1:
            return False
        Xc = (corners - T[:3, 3]) @ T[:3, :3]
        if np.any(Xc[:, 2] < 0.3):
            return False
        uv, _ = self.camera.project(Xc)
        lo, hi = uv.min(0), uv.max(0)
        full = np.prod(np.maximum(hi - lo, 1e-6))
        clo = np.maximum(lo, [-0.5, -0.5])
        chi = np.minimum(hi, [self.camera.width - 0.5, self.camera.height - 0.5])
        side = chi - clo
        if np.any(side <= 0) or np.prod(side) < 0.5 * full:
            return False
        if max(side) < self.inject.min_projected_px:
            return False
        return not self._behind_building(T[:3, 3], centre)

    def _behind_building(self, cam: np.ndarray, target: np.ndarray) -> bool:
        if not self._buildings:
            return False
        seg = np.linspace(cam[:2], target[:2], 24)[1:-1]
        mid = (cam[:2] + target[:2]) / 2
        r = np.linalg.norm(target[:2] - cam[:2]) / 2
        for i in self.twin.structures_near(mid, r):
            if i in self._buildings and point_in_convex(seg, self.twin.structures[i].polygon).any():
                return True
        return False

    # ------------------------------------------------------------ conflicts
    def conflicts(self, tr: Track, *, ego_margin: str = "headway") -> bool:
        ks = np.arange(tr.k0, tr.k1)
        # ego vehicle: plain traffic keeps out of the headway box, scenario actors out of the body
        ego = self.ego.safe_box[ks] if ego_margin == "headway" else self.ego.box[ks]
        margin = 0.0 if ego_margin == "headway" else 0.3
        ego_c = ego.mean(1)
        near = np.linalg.norm(ego_c - tr.xy, axis=1) < tr.radius + EGO_LENGTH + 40.0
        self.reason = "overlaps the ego vehicle or its path"
        for i in np.nonzero(near)[0]:
            if convex_overlap(tr.corners[i], ego[i], margin):
                return True
        self.reason = "overlaps another virtual object"
        for o in self.tracks:
            a, b = max(tr.k0, o.k0), min(tr.k1, o.k1)
            if a >= b:
                continue
            pa, pb = tr.xy[a - tr.k0:b - tr.k0], o.xy[a - o.k0:b - o.k0]
            close = np.linalg.norm(pa - pb, axis=1) < tr.radius + o.radius + CLEARANCE_M
            for j in np.nonzero(close)[0]:
                if convex_overlap(tr.corners[a - tr.k0 + j], o.corners[a - o.k0 + j], CLEARANCE_M):
                    return True
        # structures: check where the footprint comes near one (a signal head is mounted
        # on its pole above head height, so it is exempt)
        if len(self.twin.structures) and tr.cls != "traffic light":
            d = np.linalg.norm(tr.xy[:, None, :] - self.twin._st_center[None], axis=2)
            hit = d < self.twin._st_radius[None] + tr.radius + 0.1
            for i, s in zip(*np.nonzero(hit)):
                if convex_overlap(tr.corners[i], self.twin.structures[s].polygon, 0.05):
                    self.reason = "inside a structure of the twin"
                    return True
        if self.real is not None:
            crossing = tr.scenario in ("jaywalker", "occluded_pedestrian")
            kerb = tr.cls == "bicycle" or (tr.cls == "motorcycle" and "rider" not in tr.variant)
            for i, k in enumerate(range(tr.k0, tr.k1)):
                z, h = tr.z[i], tr.dims[2]
                if tr.variant.get("pole"):  # its pole is drawn: checked from the ground up
                    z, h = z - tr.variant["mount_height_m"], h + tr.variant["mount_height_m"]
                why = self.real.reject(k, self.ego.T[k], tr.cls, tr.corners[i], z, h, crossing=crossing, kerb=kerb)
                if why:
                    self.reason = why
                    return True
        why = self.extra_conflict(tr)
        if why:
            self.reason = why
            return True
        return False

    def extra_conflict(self, tr: Track) -> str | None:
        """A subclass's own rule (plan windows, scene.windows): why the track may not be, or None."""
        return None

    # ------------------------------------------------------------ trajectories
    def _limit(self, k0: int, xy: np.ndarray) -> int:
        """Frames until the track leaves the range of interest (or the sequence ends)."""
        if not self.inject.sequences:
            return 1
        cam = self.ego.cam[k0:k0 + len(xy), :2]
        far = np.nonzero(np.linalg.norm(xy - cam, axis=1) > MAX_TRACK_RANGE_M)[0]
        return int(far[0]) if len(far) else len(xy)

    def _frames_from(self, k0: int) -> np.ndarray:
        return self.times[k0:] - self.times[k0] if self.inject.sequences else np.zeros(1)

    def lane_track(self, k0, cls, variant, dims, road, index, direction, s0, speed, lat=0.0,
                   lat_profile=None, scenario=None, reverse=False) -> Track | None:
        """A vehicle along lane (road, index, direction) from s0; `reverse`: against the lane's
        direction (a real frame's oncoming traffic on the ground-plane twin's one-way lanes)."""
        rg = self.twin.roads[road]
        tt = self._frames_from(k0)
        chain = None if lat_profile is not None or speed <= 0 or reverse else self.twin.lane_chain(
            road, index, direction, s0, speed * tt[-1] + dims[0], self.rng)
        travel = -direction if reverse else direction
        if chain is not None:  # a map's lane goes on through a junction: follow its connecting road
            return self._chain_track(k0, cls, variant, dims, chain, speed * tt, lat * direction, scenario)
        s = s0 + travel * speed * tt
        ok = (s >= dims[0] / 2) & (s <= rg.length - dims[0] / 2)
        n = int(np.argmin(ok)) if not ok.all() else len(s)
        if n == 0:
            return None
        s, tt = s[:n], tt[:n]
        cd = rg.lane_d(index, direction, s)  # the lane centre follows a map's varying widths
        d = cd + np.full(n, lat) if lat_profile is None else cd + lat_profile(tt)
        xy = rg.line.offset_point(s, d)
        m = self._limit(k0, xy)
        if m == 0:
            return None
        if self.real is not None:  # and a real frame's painted lines, over the frames kept
            s, tt, d = s[:m], tt[:m], d[:m] + self._real_lane_shifts(k0, rg, index, direction, s[:m], tt[:m])
            xy, n = rg.line.offset_point(s, d), m
        _, tan = rg.line.at(s)
        yaw = np.arctan2(tan[:, 1], tan[:, 0]) + (0.0 if travel > 0 else math.pi)
        if n > 1 and lat_profile is not None:  # heading follows the lane change
            left_rate = np.gradient(d, tt) * travel if n > 2 else np.zeros(n)
            yaw = yaw + np.arctan2(left_rate, max(speed, 0.5))
        return self._road_track(cls, variant, dims, k0, xy[:m], wrap_angle(yaw[:m]), scenario)

    def _real_lanes(self, k, rg, index, direction, s, cd=None, xy=None):
        """Frame k's real lanes where a vehicle of twin lane (index, direction) is at arc length
        s: (n, y, centres, w) = the twin lane's number from the twin's ego lane (0 the camera's,
        +1 left), its centre's world y, the world y of each real lane's centre by number
        (`RealScene.lane_centres`) and the lane width; None without lines. The ground-plane
        twin's lanes are the job's width with the camera on a lane centre, the real ones are
        where the paint is."""
        ego = self.ego.lane[k] if self.real is not None else None
        if ego is None or self.twin.roads[ego.road] is not rg:
            return None
        if cd is None:  # `cd`, `xy`: the lane centre's offset and point at s when the caller has them
            cd = float(rg.lane_d(index, direction, np.array([s]))[0])
            xy = rg.line.offset_point(np.array([s]), np.array([cd]))[0]
        x, y = xy
        centres = self.real.lane_centres(k, self.ego.T[k], float(x), ego.width)
        return None if centres is None else (int(round((cd - ego.center_d) / ego.width)), float(y), centres,
                                             ego.width)

    def _real_lane_shifts(self, k0, rg, index, direction, s, tt=(0.0,)) -> np.ndarray | float:
        """Metres to add to a track's twin lane centre offset in its frames k0, k0 + 1, ... (at
        times tt from k0) so that it runs along the matching real lane. The real lane is
        matched at the track's first frame with lines and kept: it moves only when the camera
        itself changes real lane (its ego lane's centre steps by a lane width), not when the
        camera crosses a boundary of the twin's lanes, which lie elsewhere (a vehicle jumped a
        lane there). On video the shifts keep the vehicle in its painted lane however the ego
        motion drifts across the road, smoothed over LANE_SMOOTH_S (each frame's lines are a
        few cm apart from the next's); a frame without lines takes its neighbours', a track
        without any the nearest frame's with lines (video only: stills do not share a world)."""
        if self.real is None:
            return 0.0
        s = np.asarray(s, float)
        # the lane geometry of every frame in one pass (the planner asks for thousands of frames per spawn)
        geo = None
        if rg is not None:
            cd = rg.lane_d(index, direction, s)
            geo = (cd, rg.line.offset_point(s, cd))
        rows = [self._real_lanes(k0 + i, rg, index, direction, float(si), *(() if geo is None else
                                                                              (float(geo[0][i]), geo[1][i])))
                for i, si in enumerate(s)]
        ref = next((r for r in rows if r is not None), None)
        if ref is None:
            near = np.argsort(np.abs(self.times - self.times[k0]))[:LANE_BORROW_FRAMES] if self.inject.sequences else []
            for k in near:
                r = self._real_lanes(int(k), rg, index, direction, float(s[0]))
                if r is not None and r[0] in r[2]:
                    return r[2][r[0]] - r[1]
            return 0.0
        n_ref, ego_ref = ref[0], ref[2][0]
        shifts = np.full(len(rows), np.nan)
        for i, r in enumerate(rows):
            if r is not None:
                n = n_ref - int(round((r[2][0] - ego_ref) / r[3]))
                shifts[i] = r[2][n] - r[1] if n in r[2] else np.nan
        ok = np.isfinite(shifts)
        if not ok.any():
            return 0.0
        t = np.asarray(tt, float)[:len(shifts)]
        t_ok, v_ok = t[ok], shifts[ok]
        # Gaussian weights within 4 sigma (a track can last a whole video: no n x n matrix); a
        # frame farther than that from any line takes the nearest frame's
        lo = np.searchsorted(t_ok, t - 4 * LANE_SMOOTH_S)
        hi = np.searchsorted(t_ok, t + 4 * LANE_SMOOTH_S, side="right")
        j = np.clip(np.searchsorted(t_ok, t), 1, len(t_ok) - 1) if len(t_ok) > 1 else np.zeros(len(t), int)
        if len(t_ok) > 1:
            j -= (t - t_ok[j - 1]) < (t_ok[j] - t)  # the earlier neighbour when it is nearer
        nearest = v_ok[j]
        out = np.empty(len(t))
        for i, (a, b) in enumerate(zip(lo, hi)):
            w = np.exp(-0.5 * ((t_ok[a:b] - t[i]) / LANE_SMOOTH_S) ** 2)
            out[i] = w @ v_ok[a:b] / w.sum() if b > a else nearest[i]
        return out

    def _road_track(self, cls, variant, dims, k0, xy, yaw, scenario):
        """A wheeled track on the road surface: its height, pitch and roll follow the road."""
        if len(xy) == 0:
            return None
        if not self.twin.relief:
            return self._track(cls, variant, dims, k0, xy, np.zeros(len(xy)), yaw, scenario)
        z, pitch, roll = self.twin.surface_pose(xy, yaw, dims[0], dims[1])
        tr = Track(0, cls, variant, dims, k0, xy, z, yaw, scenario, None, pitch=pitch, roll=roll)
        return tr

    def _chain_track(self, k0, cls, variant, dims, chain, dist, lat, scenario):
        """A vehicle along a lane chain (through a junction); `lat` left of travel."""
        n = int(np.searchsorted(dist, chain.length - dims[0] / 2, side="right"))
        if n == 0:
            return None
        p, tan = chain.at(dist[:n])
        xy = p + lat * np.stack([-tan[:, 1], tan[:, 0]], axis=1)
        m = self._limit(k0, xy)
        return self._road_track(cls, variant, dims, k0, xy[:m], wrap_angle(np.arctan2(tan[:m, 1], tan[:m, 0])),
                                scenario)

    def walk_track(self, k0, variant, dims, start, direction_xy, speed, allowed, scenario=None,
                   stop_at=None) -> Track | None:
        """A pedestrian walking from `start` along `direction_xy`; it stops (and stands) at the
        last point where `allowed(points)` holds, or after `stop_at` metres."""
        tt = self._frames_from(k0)
        u = np.asarray(direction_xy, float) / np.linalg.norm(direction_xy)
        dist = speed * tt
        if stop_at is not None:
            dist = np.minimum(dist, stop_at)
        xy = np.asarray(start, float)[None] + dist[:, None] * u[None]
        ok = allowed(xy)
        if not ok[0]:
            return None
        if not ok.all():
            first_bad = int(np.argmin(ok))
            xy[first_bad:] = xy[first_bad - 1]
        yaw = np.full(len(xy), math.atan2(u[1], u[0]))
        m = self._limit(k0, xy)
        z = self.twin.ground_heights(xy[:m])
        return self._track("person", variant, dims, k0, xy[:m], z, yaw[:m], scenario)

    def static_track(self, k0, cls, variant, dims, xy, yaw, z=0.0, scenario=None, states=None):
        n = len(self._frames_from(k0))
        xy = np.repeat(np.asarray(xy, float)[None], n, axis=0)
        m = self._limit(k0, xy)
        return self._track(cls, variant, dims, k0, xy[:m], np.full(m, z), np.full(m, yaw), scenario,
                           states[:m] if states else None)

    def _track(self, cls, variant, dims, k0, xy, z, yaw, scenario=None, states=None):
        if len(xy) == 0:
            return None
        return Track(0, cls, variant, dims, k0, xy, z, yaw, scenario, states)

    def accept(self, tr: Track) -> Track:
        tr.id = self.next_id
        self.next_id = self.next_id % (SCENERY_ID - 1) + 1
        if "rider" in tr.variant:
            tr.rider_id = self.next_id
            self.next_id = self.next_id % (SCENERY_ID - 1) + 1
        self.tracks.append(tr)
        return tr

    # ------------------------------------------------------------ spawning by class
    def _view_point(self, k: int) -> np.ndarray:
        r = self.rng.uniform(max(self.d0, 3.0), self.d1)
        b = self.ego.yaw[k] + self.rng.uniform(-0.5, 0.5) * self.hfov * 0.95
        return self.ego.cam[k, :2] + r * np.array([math.cos(b), math.sin(b)])

    def spawn(self, cls: str, k: int) -> Track | None:
        procedural = sample_variant(cls, self.rng)
        drawn = self.assets.draw(cls, self.asset_rng) if self.assets is not None else None
        variant, dims = drawn or procedural
        p = self._view_point(k)
        if cls in VEHICLES + ("bicycle",) and self.real is not None and self.real.has(k, ROAD):
            edge = cls == "bicycle" or (cls == "motorcycle" and "rider" not in variant)
            motorway = self._motorway(k) if edge else None
            if motorway:
                self.reason = f"{motorway}: no parking or cycling on its edge"
                return None
            if cls == "bicycle" and "rider" not in variant and not self.real.has(k, BAND):
                # the analysis found no pavement (a highway's verge, a barrier): no one walks
                # here, so no one parked a bicycle here either
                self.reason = "no pavement beside the road for a parked bicycle"
                return None
            T = self.ego.T[k]
            p = self.real.sample_ground(k, ROAD_EDGE if edge else ROAD, T, self.rng, self.d0, self.d1,
                                        keep=(lambda g: self.real.kerb_side(k, T, g)) if edge else None)
            if p is None:
                self.reason = (f"no estimated road {'edge on the kerb side ' if edge else ''}between {self.d0:g} "
                               f"and {self.d1:g} m")
                return None
        if cls in VEHICLES or cls == "bicycle":
            return self._spawn_on_road(cls, variant, dims, k, p)
        if cls == "person":
            if self.real is not None and self.real.has(k, BAND):
                return self._spawn_on_band(variant, dims, k)
            return self._spawn_person(variant, dims, k, p)
        return self._spawn_signal(variant, dims, k)

    def _motorway(self, k: int) -> str | None:
        """Why frame k's real road is a motorway, or None: no map tells it on real footage, and
        cyclists, pedestrians, parked two-wheelers and traffic lights have no place there.
        On video the ego's speed: 80 km/h where the frame shows no centre line (a divided
        road: the freeway video runs 88-93 km/h), 100 km/h on a two-way road (a rural road at
        90 km/h may carry cyclists). A still has no speed: no centre line and nothing to walk
        on beside the road (the Udacity freeway photos) make it a divided highway; a two-way
        road without a centre line or pavement then loses its cyclists, the cautious side."""
        if self.real is None:
            return None
        divided = self.real.centre_line(k) is None  # all traffic runs the ego's way
        if self.inject.sequences:
            v = float(self.ego.speed[k])
            if v > MOTORWAY_MPS or (divided and v > MOTORWAY_DIVIDED_MPS):
                return f"the camera moves at {v * 3.6:.0f} km/h: a motorway"
            return None
        if divided and self.real.has(k, ROAD) and not self.real.has(k, BAND):
            return "no centre line and nothing to walk on beside the road: a divided highway"
        return None

    def _real_frame_limits(self, k: int) -> tuple[str | None, list[dict]]:
        """A real frame's limits on placement: (why it takes no object at all, or None; its
        decisions for the manifest). Sets the far end of the distance range (self.d1) for frame
        k: objects beyond the camera's `max_distance` would float above or sink into the road."""
        self.d1 = self.inject.distance_m[1]
        if self.real is None:
            return None, []
        shut = self.real.closed(k)
        lim, why = self.real.max_distance(k)
        if shut is not None or lim >= self.d1:
            return shut, []
        if lim <= self.d0:
            return f"no distance of the job's {self.d0:g}-{self.d1:g} m is safe: {why}", []
        self.d1 = lim
        return None, [{"what": "max_distance_m", "value": round(lim, 1), "reason": why}]

    def _closed(self, cls: str, k: int, rejected: dict) -> bool:
        motorway = self._motorway(k) if cls in MOTORWAY_CLOSED else None
        if motorway:
            rejected[cls, f"{motorway}, without cyclists, pedestrians or traffic lights"] = 1
        return bool(motorway)

    def _spawn_on_road(self, cls, variant, dims, k, p):
        lane = self.twin.lane_at(p[0], p[1])
        if lane is None or lane.in_junction:
            return None
        rg = self.twin.roads[lane.road]
        rider = "rider" in variant
        lat = 0.0
        if self.real is not None and (cls == "bicycle" or (cls == "motorcycle" and not rider)):
            lat = lane.lateral  # where it was sampled: the real road's edge
        elif cls == "bicycle" or (cls == "motorcycle" and not rider):
            # bicycles (and parked motorcycles) keep to the curb side of the outermost lane
            n = rg.spec.lanes_forward if lane.direction > 0 else rg.spec.lanes_backward
            lane = self.twin.lane_at(*rg.line.offset_point(
                lane.s, (-1 if lane.direction > 0 else 1) * (rg.spec.median_m / 2 + (n - 0.5) * lane.width))[0])
            if lane is None or lane.in_junction:
                return None
            lat = -(lane.width / 2 - 0.3 - dims[1] / 2)  # to the right of travel
        elif cls == "motorcycle":
            lat = float(self.rng.uniform(-0.6, 0.6))
        moving = rider if cls in ("bicycle", "motorcycle") else self.rng.random() < 0.8
        speed = self._speed(cls, k) if moving else 0.0
        # a real frame's far side of its centre line: the ground-plane twin's lanes all run with
        # the ego, so the vehicle keeps the lane and travels against it (and is parked facing so)
        towards = False
        if self.real is not None:  # decided where the vehicle will be, not where it was sampled
            cd = rg.lane_d(lane.index, lane.direction, np.array([lane.s])) + self._real_lane_shifts(
                k, rg, lane.index, lane.direction, [lane.s])
            xy = rg.line.offset_point(np.array([lane.s]), cd + lat * lane.direction)[0]
            towards = self.real.oncoming(k, self.ego.T[k], xy)
        # `lat` is relative to the travel direction (left > 0); lane_track wants road-frame d
        return self.lane_track(k, cls, variant, dims, lane.road, lane.index, lane.direction, lane.s,
                               speed, lat=lat * lane.direction, reverse=towards)

    def _speed(self, cls: str, k: int) -> float:
        """A moving road user's speed: its class's range; on real video with the camera moving,
        a vehicle's is the real traffic's, the ego's speed x FLOW_SPEED (virtual cars at city
        speeds on a real freeway were overtaken by the camera and the real traffic as if parked)."""
        lo, hi = SPEED[cls]
        v_ego = float(self.ego.speed[k]) if self.inject.sequences else 0.0
        if self.real is not None and cls in VEHICLES and v_ego > FLOW_MIN_EGO_MPS:
            lo, hi = v_ego * FLOW_SPEED[0], v_ego * FLOW_SPEED[1]
        return lo + (hi - lo) * float(self.rng.random())  # one draw, as rng.uniform(lo, hi)

    def _spawn_person(self, variant, dims, k, p):
        tw = self.twin
        if tw.crosswalks and not any(rg.spec.sidewalk_m >= 1.0 for rg in tw.roads.values()):
            # a map without sidewalks (many OpenDRIVE maps): pedestrians cross on its crosswalks,
            # which maps often put inside the junction
            c = np.array([cw.mean(0) for cw in tw.crosswalks])
            j = int(np.argmin(np.linalg.norm(c - p, axis=1)))
            if np.linalg.norm(c[j] - p) > 30:
                return None
            road, s0, s1 = tw.crosswalk_info[j]
            rg = tw.roads[road]
            s = float(self.rng.uniform(s0 + 0.3, s1 - 0.3)) if s1 - s0 > 0.6 else (s0 + s1) / 2
            start = rg.line.offset_point(s, float(self.rng.uniform(-rg.hw_r(s) + 0.5, rg.hw_l(s) - 0.5)))[0]
            _, t = rg.line.at(s)
            across = np.array([-t[0, 1], t[0, 0]]) * (1 if self.rng.random() < 0.5 else -1)
            return self.walk_track(k, variant, dims, start, across, float(self.rng.uniform(*SPEED["person"])),
                                   tw.crosswalk_mask)
        if tw.on_crosswalk(*p) and not tw.in_junction(*p):
            lane_roads = [(rg, float(s[0]), float(d[0])) for rg in tw.roads.values()
                          for s, d, _ in [rg.line.project(p)]]
            rg, s, d = min(lane_roads, key=lambda r: abs(r[2]) if r[0].carriageway(r[1], r[2]) else 1e9)
            _, t = rg.line.at(s)
            normal = np.array([-t[0, 1], t[0, 0]]) * (1 if self.rng.random() < 0.5 else -1)
            allowed = lambda xy: tw.crosswalk_mask(xy) | tw.sidewalk_mask(xy)  # noqa: E731
            speed = float(self.rng.uniform(*SPEED["person"]))
            return self.walk_track(k, variant, dims, p, normal, speed, allowed)
        if not tw.on_sidewalk(*p):
            # snap to the nearest sidewalk across the road's cross-section
            best = None
            for rg in tw.roads.values():
                if rg.spec.sidewalk_m < 1.0:
                    continue
                s, d, _ = rg.line.project(p)
                s, d = float(s[0]), float(d[0])
                edge = float(-rg.hw_r(s) if d < 0 else rg.hw_l(s))
                dd = edge + math.copysign(rg.spec.sidewalk_m * self.rng.uniform(0.25, 0.75), edge)
                if abs(dd - d) < 12 and (best is None or abs(dd - d) < best[0]):
                    best = (abs(dd - d), rg.line.offset_point(s, dd)[0])
            if best is None:
                return None
            p = best[1]
            if not tw.on_sidewalk(*p):
                return None
        rg, s = None, 0.0
        for cand in tw.roads.values():
            cs, cdd, _ = cand.line.project(p)
            if cand.sidewalk_band(cs, cdd)[0]:
                rg, s = cand, float(cs[0])
                break
        _, t = rg.line.at(s)
        walking = variant["kind"] == "walking"
        if walking:
            u = t[0] * (1 if self.rng.random() < 0.5 else -1)
            speed = float(self.rng.uniform(*SPEED["person"]))
        else:
            a = self.rng.uniform(-math.pi, math.pi)
            u, speed = np.array([math.cos(a), math.sin(a)]), 0.0
        return self.walk_track(k, variant, dims, p, u, speed, tw.sidewalk_mask)

    def _spawn_on_band(self, variant, dims, k):
        """A pedestrian on the real frame's walkable band: standing, or walking along the road."""
        p = self.real.sample_ground(k, BAND, self.ego.T[k], self.rng, self.d0, self.d1)
        if p is None:
            self.reason = f"no walkable band beside the road between {self.d0:g} and {self.d1:g} m"
            return None
        if variant["kind"] == "walking":
            u, speed = np.array([1.0 if self.rng.random() < 0.5 else -1.0, 0.0]), float(self.rng.uniform(*SPEED["person"]))
        else:
            a = self.rng.uniform(-math.pi, math.pi)
            u, speed = np.array([math.cos(a), math.sin(a)]), 0.0
        return self.walk_track(k, variant, dims, p, u, speed, lambda xy: np.ones(len(xy), bool))

    def _spawn_signal(self, variant, dims, k):
        slots = self.twin.signal_slots
        if not slots:
            return self._spawn_signal_on_pole(variant, dims, k) if self.real is not None else None
        sl = slots[int(self.rng.integers(len(slots)))]
        z = self.twin.ground_height(sl.x, sl.y) + variant["mount_height_m"]
        # the head hangs in front of the slot's signal pole (radius 0.07 m), facing the traffic
        off = dims[0] / 2 + 0.09
        xy = (sl.x + off * math.cos(sl.yaw), sl.y + off * math.sin(sl.yaw))
        tt = self.times[k:] if self.inject.sequences else self.times[k:k + 1]
        offset = float(self.rng.uniform(0, sum(d for _, d in SIGNAL_CYCLE)))
        states = [signal_state(t + offset) for t in tt]
        return self.static_track(k, "traffic light", variant, dims, xy, sl.yaw, z, states=states)

    def _spawn_signal_on_pole(self, variant, dims, k):
        """Ground-plane scenes: the head on a pole of its own just beyond the road edge, facing
        the ego traffic. The pole is rendered and composited but never labelled (COCO boxes the
        head), so it may not stand behind a real object or on the road (RealScene.reject)."""
        T = self.ego.T[k]
        p = self.real.sample_ground(k, ROAD_EDGE, T, self.rng, max(self.d0, 8.0), self.d1)
        if p is None:
            self.reason = f"no road edge between {max(self.d0, 8.0):g} and {self.d1:g} m to stand a signal pole at"
            return None
        fwd = np.array([math.cos(self.ego.yaw[k]), math.sin(self.ego.yaw[k])])
        side = 1.0 if fwd[0] * (p[1] - T[1, 3]) - fwd[1] * (p[0] - T[0, 3]) > 0 else -1.0
        out = side * np.array([-fwd[1], fwd[0]])  # away from the road, on the edge's side
        pole = p + out * self.rng.uniform(*POLE_OFF_ROAD_M)
        variant = {**variant, "pole": True}
        # the head hangs in front of its pole (radius 0.06 m), facing against the ego heading
        yaw = float(self.ego.yaw[k] + math.pi)
        xy = pole + (dims[0] / 2 + 0.07) * np.array([math.cos(yaw), math.sin(yaw)])
        z = self.twin.ground_height(*xy) + variant["mount_height_m"]
        tt = self.times[k:] if self.inject.sequences else self.times[k:k + 1]
        offset = float(self.rng.uniform(0, sum(d for _, d in SIGNAL_CYCLE)))
        return self.static_track(k, "traffic light", variant, dims, xy, yaw, z,
                                 states=[signal_state(t + offset) for t in tt])

    # ------------------------------------------------------------ scenarios
    def stage_scenario(self, name: str, k: int) -> list[Track]:
        lane = self.ego.lane[k]
        near_crosswalk = name == "jaywalker" and self.twin.crosswalks  # needs no ego lane
        if not near_crosswalk and (lane is None or lane.in_junction):
            return []
        rg = self.twin.roads[lane.road] if lane is not None else None
        fn = {"jaywalker": self._jaywalker, "cut_in": self._cut_in, "near_collision": self._near_collision,
              "occluded_pedestrian": self._occluded_pedestrian, "cyclist_overtake": self._cyclist}[name]
        for _ in range(6):
            tracks = fn(k, lane, rg)
            if not tracks or any(t is None for t in tracks):
                continue
            ok, staged = True, []
            for tr in tracks:
                if self.conflicts(tr, ego_margin="body"):
                    ok = False
                    break
                staged.append(tr)
                self.tracks.append(tr)  # later actors of the scenario check against earlier ones
            for tr in staged:
                self.tracks.remove(tr)
            if ok and any(self.visible(t, k) for t in tracks):
                return [self.accept(t) for t in tracks]
        return []

    def _ahead(self, lane, rg, dist):
        """Road arc length `dist` metres ahead of the ego along its lane direction."""
        return lane.s + lane.direction * dist

    def _jaywalker(self, k, lane, rg):
        """A pedestrian crossing the road off a crosswalk: just beside one of the twin's
        crosswalks in view when it has them (where people cut across), else mid-block across
        the ego's road, away from junctions."""
        v, dims = sample_variant("person", self.rng)
        v["kind"] = "walking"
        v["stride_rad"] = v["stride_rad"] or 0.35
        if self.twin.crosswalks:
            return self._jaywalk_near_crosswalk(k, v, dims)
        dist = self.rng.uniform(max(self.d0, 12.0), min(self.d1, 35.0))
        s = self._ahead(lane, rg, dist)
        if not 2 < s < rg.length - 2:
            return None
        side = 1 if self.rng.random() < 0.5 else -1
        d_start = float(rg.hw_l(s) + 0.4) if side > 0 else -float(rg.hw_r(s) + 0.4)
        start = rg.line.offset_point(s, d_start)[0]
        if self.twin.on_crosswalk(*start):
            return None
        # mid-block: the crossing and 5 m either side of it keep clear of junctions
        dd = np.linspace(-float(rg.hw_r(s)), float(rg.hw_l(s)), 7)
        probe = np.vstack([rg.line.offset_point(np.full(7, s + ds), dd) for ds in (-5.0, 0.0, 5.0)])
        if self.twin.junction_mask(probe).any():
            return None
        _, t = rg.line.at(s)
        normal = np.array([-t[0, 1], t[0, 0]]) * -side
        width = float(rg.hw_l(s) + rg.hw_r(s)) + 1.6
        speed = float(self.rng.uniform(1.2, 1.9))
        allowed = lambda xy: np.ones(len(xy), bool)  # noqa: E731 - jaywalking: anywhere
        return [self.walk_track(k, v, dims, start, normal, speed, allowed, "jaywalker", stop_at=width)]

    def _jaywalk_near_crosswalk(self, k, v, dims):
        tw, cam = self.twin, self.ego.cam[k, :2]
        fwd = self.ego.heading[k]
        cands = []
        for j, (road, s0, s1) in enumerate(tw.crosswalk_info):
            c = tw.crosswalks[j].mean(0)
            rel = c - cam
            dist = float(np.linalg.norm(rel))
            if max(self.d0, 8.0) <= dist <= min(self.d1, 45.0) and rel @ fwd > 0.8 * dist:  # ahead, in view
                cands.append(j)
        if not cands:
            return None
        road, s0, s1 = tw.crosswalk_info[cands[int(self.rng.integers(len(cands)))]]
        rg = tw.roads[road]
        off = float(self.rng.uniform(0.6, 4.0))  # beside the zebra, not on it
        options = [x for x in (s1 + off, s0 - off) if 0.5 < x < rg.length - 0.5]
        if not options:
            return None
        s = options[int(self.rng.integers(len(options)))]
        side = 1 if self.rng.random() < 0.5 else -1
        start = rg.line.offset_point(s, side * (float(rg.hw_l(s) if side > 0 else rg.hw_r(s)) + 0.4))[0]
        _, t = rg.line.at(s)
        normal = np.array([-t[0, 1], t[0, 0]]) * -side
        width = float(rg.hw_l(s) + rg.hw_r(s)) + 1.6
        allowed = lambda xy: np.ones(len(xy), bool)  # noqa: E731 - jaywalking: anywhere
        return [self.walk_track(k, v, dims, start, normal, float(self.rng.uniform(1.2, 1.9)), allowed,
                                "jaywalker", stop_at=width)]

    def _cut_in(self, k, lane, rg):
        """A vehicle from a neighbouring lane of the ego's direction cuts in ahead: only on a
        multi-lane road segment, never in a junction (nor on a map's connecting road)."""
        if rg.spec.junction is not None:
            return None
        n = rg.spec.lanes_forward if lane.direction > 0 else rg.spec.lanes_backward
        neighbours = [i for i in (lane.index - 1, lane.index + 1) if 0 <= i < n]
        if not neighbours:
            return None
        j = neighbours[int(self.rng.integers(len(neighbours)))]
        cls = "car" if self.rng.random() < 0.8 else "motorcycle"
        v, dims = sample_variant(cls, self.rng)
        if cls == "motorcycle" and "rider" not in v:
            return None
        gap = self.rng.uniform(5.0, 14.0)
        s0 = self._ahead(lane, rg, EGO_FRONT_OF_CAM + gap + dims[0] / 2)
        v_e = float(np.median(self.ego.speed[k:k + 10]))
        speed = max(4.0, v_e + self.rng.uniform(0.5, 2.5))
        cd_from = float(rg.lane_d(j, lane.direction, lane.s))
        delta = lane.center_d - cd_from
        # cosine profile; duration keeps the heading within 8 deg of the lane
        T = max(2.5, math.pi * abs(delta) / (2 * speed * math.tan(math.radians(8.0))))
        t_start = self.rng.uniform(0.3, 1.0)

        def prof(tt):
            x = np.clip((tt - t_start) / T, 0, 1)
            return delta * (1 - np.cos(math.pi * x)) / 2

        tr = self.lane_track(k, cls, v, dims, rg.id, j, lane.direction, s0, speed, lat_profile=prof,
                             scenario="cut_in")
        if tr is None or self.twin.junction_mask(tr.xy).any():
            return None
        return [tr]

    def _near_collision(self, k, lane, rg):
        cls = str(self.rng.choice(["car", "car", "truck", "bus"]))
        v, dims = sample_variant(cls, self.rng)
        v_e = float(np.median(self.ego.speed[k:k + 10]))
        g0 = self.rng.uniform(12.0, 25.0)
        g_min = self.rng.uniform(1.0, 3.0)
        window = float(self.rng.uniform(2.5, 4.0))
        speed = max(0.0, v_e - (g0 - g_min) / window)  # the lead closes to g_min, then waits
        s0 = self._ahead(lane, rg, EGO_FRONT_OF_CAM + g0 + dims[0] / 2)
        tr = self.lane_track(k, cls, v, dims, rg.id, lane.index, lane.direction, s0, speed,
                             scenario="near_collision")
        if tr is None:
            return None
        # after the window the lead stops dead: the ego path ends in a near miss
        tt = self.times[tr.k0:tr.k1] - self.times[tr.k0]
        stop = np.searchsorted(tt, window)
        if stop < len(tt):
            tr.xy[stop:] = tr.xy[stop - 1 if stop else 0]
            for arr in (tr.yaw, tr.z, tr.pitch, tr.roll):
                arr[stop:] = arr[stop - 1 if stop else 0]
            tr.__post_init__()
        # cut the track where the ego would get within g_min/2 of it
        ks = np.arange(tr.k0, tr.k1)
        for i, kk in enumerate(ks):
            if convex_overlap(tr.corners[i], self.ego.box[kk], g_min / 2):
                return [self._truncate(tr, i)] if i > 0 else None
        return [tr]

    def _truncate(self, tr: Track, n: int) -> Track:
        return Track(tr.id, tr.cls, tr.variant, tr.dims, tr.k0, tr.xy[:n], tr.z[:n], tr.yaw[:n], tr.scenario,
                     tr.states[:n] if tr.states else None, pitch=tr.pitch[:n], roll=tr.roll[:n])

    def _occluded_pedestrian(self, k, lane, rg):
        # parked cars along the curb of the ego's side if the ego is not in the curb lane,
        # else along the opposite curb
        n_same = rg.spec.lanes_forward if lane.direction > 0 else rg.spec.lanes_backward
        if lane.index < n_same - 1:
            direction, idx = lane.direction, n_same - 1
        else:
            n_opp = rg.spec.lanes_backward if lane.direction > 0 else rg.spec.lanes_forward
            if n_opp == 0:
                return None
            direction, idx = -lane.direction, n_opp - 1
        curb_side = -1 if direction > 0 else 1  # d sign of this curb
        if rg.spec.sidewalk_m < 1.0:
            return None
        cd = float(rg.lane_d(idx, direction, lane.s))
        w_idx = float(rg.lane_width(idx, direction, lane.s))
        dist = self.rng.uniform(max(self.d0, 12.0), min(self.d1, 30.0))
        s_gap = self._ahead(lane, rg, dist)
        gap = self.rng.uniform(1.2, 1.8)
        out = []
        s_cursor = {+1: s_gap + gap / 2, -1: s_gap - gap / 2}
        for sgn in (+1, -1):
            v, dims = sample_variant("car", self.rng)
            s_c = s_cursor[sgn] + sgn * dims[0] / 2
            if not dims[0] / 2 <= s_c <= rg.length - dims[0] / 2:
                return None
            lat_d = cd + curb_side * (w_idx / 2 - dims[1] / 2 - 0.25)
            p = rg.line.offset_point(s_c, lat_d)[0]
            _, t = rg.line.at(s_c)
            yaw = math.atan2(t[0, 1], t[0, 0]) + (0 if direction > 0 else math.pi)
            n = len(self._frames_from(k))
            xy = np.repeat(p[None], n, axis=0)
            m = self._limit(k, xy)
            out.append(self._road_track("car", v, dims, k, xy[:m], np.full(m, yaw), "occluded_pedestrian"))
        pv, pdims = sample_variant("person", self.rng)
        pv["kind"], pv["stride_rad"] = "walking", max(pv["stride_rad"], 0.3)
        edge = curb_side * float(rg.hw_r(s_gap) if curb_side < 0 else rg.hw_l(s_gap))
        start = rg.line.offset_point(s_gap, edge + curb_side * 0.6)[0]
        end_d = cd - curb_side * (w_idx / 2 - 0.35)  # peeks just past the cars
        _, t = rg.line.at(s_gap)
        normal = np.array([-t[0, 1], t[0, 0]]) * -curb_side
        allowed = lambda xy: np.ones(len(xy), bool)  # noqa: E731
        out.append(self.walk_track(k, pv, pdims, start, normal, float(self.rng.uniform(1.0, 1.5)), allowed,
                                   "occluded_pedestrian", stop_at=abs(end_d - edge) + 0.6))
        return out

    def _cyclist(self, k, lane, rg):
        v, dims = sample_variant("bicycle", self.rng)
        if "rider" not in v:
            return None
        n = rg.spec.lanes_forward if lane.direction > 0 else rg.spec.lanes_backward
        dist = self.rng.uniform(max(self.d0, 8.0), min(self.d1, 25.0))
        s0 = self._ahead(lane, rg, dist)
        lat = -(float(rg.lane_width(n - 1, lane.direction, s0)) / 2 - 0.3 - dims[1] / 2)
        return [self.lane_track(k, "bicycle", v, dims, rg.id, n - 1, lane.direction, s0,
                                float(self.rng.uniform(4.0, 6.5)), lat=lat * lane.direction,
                                scenario="cyclist_overtake")]

    # ------------------------------------------------------------ main loop
    def run(self, on_progress=None) -> list[FramePlan]:
        lo, hi = self.inject.objects_per_frame
        target, target_until = 0, -1.0
        last_staged = {s: -1e9 for s in self.inject.scenarios}
        retry_at = {s: -1e9 for s in self.inject.scenarios}
        plans = []
        for k, (frame_id, t, T) in enumerate(self.poses[:self.n_plan]):
            if on_progress is not None:
                on_progress(k)
            if not self.inject.sequences:
                self.tracks = []
            if t >= target_until or not self.inject.sequences:
                target = int(self.rng.integers(lo, hi + 1))
                target_until = t + TARGET_PERIOD_S
            shut, frame_notes = self._real_frame_limits(k)
            for name in self.inject.scenarios if shut is None else ():
                alive = any(tr.scenario == name and tr.k1 > k for tr in self.tracks)
                if not alive and t - last_staged[name] >= SCENARIO_PERIOD_S and t >= retry_at[name]:
                    if self.stage_scenario(name, k):
                        last_staged[name] = t
                    else:  # the geometry does not allow it here; try again a little later
                        retry_at[name] = t + SCENARIO_RETRY_S
            vis = [tr for tr in self.tracks if tr.k0 <= k < tr.k1 and self.visible(tr, k)]
            rejected: dict[tuple[str, str], int] = {}
            limit = 12 if self.real is None else 36
            failures = {c: limit for c in self.classes if self._closed(c, k, rejected)}
            if shut is not None:  # the real frame takes no object at all: each class says why
                for c in self.classes:
                    failures[c] = limit
                    rejected[c, shut] = 1
            # each open class's share of the frame's objects: refills stop at it (below)
            open_w = {c: w for c, w in zip(self.classes, self.weights) if c not in failures}
            total_w = sum(open_w.values())
            cap = {c: math.ceil(target * w / total_w) for c, w in open_w.items()} if total_w > 0 else {}
            tries, queue, streak, draws = 0, [], 0, 0
            # real frames reject more candidates (road users, road edges): more tries
            while len(vis) < target and tries < SPAWN_TRIES * (1 if self.real is None else 3) and self.classes:
                if not queue:
                    usable = [c for c in self.classes if failures.get(c, 0) < limit]
                    if draws:  # a refill after classes found no room: only classes below their
                        # share of the frame (small two-wheelers filled the room that cars and
                        # buses could not use: motorcycles were 0.48 of the Udacity photos' objects
                        # for a weight of 0.12)
                        usable = [c for c in usable if sum(tr.cls == c for tr in vis) < cap.get(c, 0)]
                    if not usable:
                        break
                    draws += 1
                    # the frame's missing objects are drawn at once and placed largest first, each
                    # with a few tries: drawn one at a time, cars and motorcycles filled the lanes
                    # before a bus or truck found room, and the weights meant little
                    w = np.array([self.weights[self.classes.index(c)] for c in usable])
                    drawn = self.rng.choice(len(usable), size=target - len(vis), p=w / w.sum())
                    queue = sorted((usable[i] for i in drawn), key=PACKING_ORDER.index)
                cls = queue[0]
                tries += 1
                streak += 1
                self.reason = ""
                tr = self.spawn(cls, k)
                why = (self.reason or NO_PLACE.get(cls, NO_PLACE[None])) if tr is None else \
                    "not visible from the camera" if not self.visible(tr, k) else \
                    self.reason if self.conflicts(tr) else None
                if why:
                    failures[cls] = failures.get(cls, 0) + 1
                    rejected[cls, why] = rejected.get((cls, why), 0) + 1
                    if streak >= SAME_CLASS_TRIES or failures[cls] >= limit:
                        queue, streak = queue[1:], 0
                    continue
                vis.append(self.accept(tr))
                queue, streak = queue[1:], 0
            objs = []
            for tr in sorted(vis, key=lambda x: x.id):
                i = k - tr.k0
                objs += split_rider(PlacedObject(
                    id=tr.id, cls=tr.cls, position=(float(tr.xy[i, 0]), float(tr.xy[i, 1]), float(tr.z[i])),
                    yaw=float(tr.yaw[i]), dims=tuple(float(x) for x in tr.dims), variant=dict(tr.variant),
                    velocity=tr.velocity(i, self.times), state=tr.states[i] if tr.states else None,
                    scenario=tr.scenario, pitch=float(tr.pitch[i]), roll=float(tr.roll[i])), tr.rider_id)
            decisions = frame_notes + [{"what": "rejected", "cls": c, "reason": r, "count": n}
                                       for (c, r), n in rejected.items()]
            if self.real is not None:
                for tr in vis:
                    i = k - tr.k0
                    cov = self.real.covered(k, T, tr.corners[i], tr.z[i], tr.dims[2])
                    if cov:
                        decisions.append({"what": "covers_real", "id": tr.id, "cls": tr.cls, "real": cov})
            plans.append(FramePlan(str(frame_id), float(t), np.asarray(T, float).tolist(), objs,
                                   decisions=decisions, camera_velocity=self.ego.velocity(k, self.inject.sequences)))
            self.tracks = [tr for tr in self.tracks if tr.k1 > k + 1]
        return plans


NO_PLACE = {"traffic light": "no signal pole, intersection slot or estimated road edge to mount a traffic light at",
            "person": "no sidewalk, band or crosswalk near the sampled point",
            None: "no lane near the sampled point"}


def unplaced_warnings(plans: list[FramePlan], inject) -> list[str]:
    """One sentence per weighted class that no frame holds, with its most common rejection."""
    placed = {o.cls for p in plans for o in p.objects}
    out = []
    for cls, w in inject.classes.items():
        if w <= 0 or cls in placed:
            continue
        reasons: dict[str, int] = {}
        for p in plans:
            for d in p.decisions:
                if d.get("what") == "rejected" and d["cls"] == cls:
                    reasons[d["reason"]] = reasons.get(d["reason"], 0) + d["count"]
        why = max(reasons, key=reasons.get) if reasons else "never drawn (its weight is small)"
        out.append(f"class {cls!r} (weight {w:g}) was placed in none of {len(plans)} frames: {why}")
    return out


def signal_state(t: float) -> str:
    cycle = sum(d for _, d in SIGNAL_CYCLE)
    x = t % cycle
    for name, d in SIGNAL_CYCLE:
        if x < d:
            return name
        x -= d
    return SIGNAL_CYCLE[-1][0]


def plan_sequence(twin: Twin, camera: Camera, poses, inject, seed: int, *, assets=None,
                  real=None, on_progress=None) -> list[FramePlan]:
    """Per-frame plans for `poses` = [(frame_id, t, T_world_cam)], deterministic per seed.

    `inject` is a `blendgen.job.schema.Inject`. With `inject.sequences` objects keep their id
    and move along their lane/path across frames; otherwise every frame is planned afresh.
    `assets` (an AssetSampler) mixes library assets in; scenario actors stay procedural.
    `real`: a `scene.real_scene.RealScene` with the real frames' constraints (ground-plane jobs).
    `on_progress(frames_done)` is called before each frame."""
    if not poses:
        return []
    return Planner(twin, camera, poses, inject, seed, assets=assets, real=real).run(on_progress)
