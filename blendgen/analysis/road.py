"""The real road in a frame: drivable surface, the bands beside it, its direction (bpy-free).

Drivable surface: a colour/texture model of the asphalt seeded just in front of the hood
(Lab colour within a Mahalanobis distance of the seed, low local texture), below the
horizon, above the hood, outside the detected road users; the connected part that holds
the seed, closed over lane markings and filled between its edges row by row. A user mask
`masks/road/<frame_id>.png` in the recording (non-zero = road) replaces the estimate.

Walkable bands: within `BAND_M` metres beside the road, the ground that looks like a pavement
(sidewalk, plaza, snow-covered verge): the road's chroma (lit by the same light, so night
tints cancel), smooth, and clearly lighter or darker than the asphalt. That last test keeps
pedestrians off a highway's asphalt shoulder; grass, dry verges, gravel and barriers fail the
chroma or texture test. A user mask `masks/sidewalk/<frame_id>.png` replaces the estimate.

Direction: the vanishing point of the road's long lines (lane markings, edges) on the
horizon, back-projected to a yaw relative to the camera's heading; the road's centreline
in the mask when no line is found.

Mask encoding (`<frame_id>_road.png`): 255 road, 128 band, 0 anything else.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from blendgen.geometry import Camera
from blendgen.ground import horizon_v, rays_world, to_ground

WORK_W = 320            # the estimate runs at this width (then scaled back up)
BAND_M = 4.0            # band width beside the road
MAX_MAHAL = 3.5         # colour distance (in seed standard deviations) still counted as road
MIN_STD_LAB = (5.0, 2.5, 2.5)   # floor on the seed's spread: flat seeds would reject everything
MIN_SEED_PX = 60
MIN_SEED_L = 8.0        # OpenCV Lab lightness 0..255; the BDD night street's asphalt is ~30
MAX_ROAD_YAW_DEG = 35.0
WALK_MAX_CHROMA = 7.0   # Lab a*b* distance to the road's median chroma (OpenCV units)
WALK_MIN_DL = 25.0      # lightness step to the asphalt: concrete vs asphalt by day, not shoulder vs lane
WALK_MIN_AREA = 0.001   # of the frame: smaller walkable specks are noise


def user_mask(recording_dir: Path, kind: str, frame_id: str, size: tuple[int, int]) -> np.ndarray | None:
    """The user's `masks/<kind>/<frame_id>.png` (road, sidewalk) as bool HxW, or None."""
    p = Path(recording_dir) / "masks" / kind / f"{frame_id}.png"
    if not p.is_file():
        return None
    m = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
    if m is None:
        from blendgen.errors import UserError

        raise UserError(f"not a readable PNG {kind} mask", where=str(p))
    if m.shape[::-1] != tuple(size):
        m = cv2.resize(m, tuple(size), interpolation=cv2.INTER_NEAREST)
    return m > 0


def estimate_road(image: np.ndarray, horizon, hood_mask: np.ndarray | None, boxes: list[list[float]],
                  ) -> tuple[np.ndarray | None, str]:
    """(road bool HxW or None, reason). `boxes`: real road users [x, y, w, h] (not road)."""
    H, W = image.shape[:2]
    s = WORK_W / W
    h, w = int(round(H * s)), WORK_W
    small = cv2.resize(image, (w, h), interpolation=cv2.INTER_AREA)
    lab = cv2.cvtColor(cv2.GaussianBlur(small, (5, 5), 0), cv2.COLOR_BGR2LAB).astype(np.float32)
    allowed = np.ones((h, w), bool)
    hz = horizon_v(horizon, np.arange(w) / s) * s
    rows = np.arange(h)[:, None]
    allowed &= rows > hz[None, :] + 0.02 * h
    hood = None
    if hood_mask is not None:
        hood = cv2.resize(hood_mask.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) > 0
        allowed &= ~hood
    objects = np.zeros((h, w), bool)
    for x, y, bw, bh in boxes:
        objects[int(y * s):int(math.ceil((y + bh) * s)) + 1, int(x * s):int(math.ceil((x + bw) * s)) + 1] = True
    allowed &= ~objects
    # seed: a patch centred just above the hood (or the image bottom)
    cols = slice(int(0.4 * w), int(0.6 * w))
    free = np.flatnonzero(allowed[:, cols].all(axis=1))
    if len(free) == 0:
        return None, "no free ground in front of the camera (all hood, horizon or road users)"
    bottom = int(free.max())
    seed = np.zeros((h, w), bool)
    seed[max(0, bottom - int(0.08 * h)):bottom + 1, cols] = True
    seed &= allowed
    if seed.sum() < MIN_SEED_PX:
        return None, f"only {int(seed.sum())} free seed pixels in front of the hood (need {MIN_SEED_PX})"
    px = lab[seed]
    mu = np.median(px, axis=0)
    if mu[0] < MIN_SEED_L:
        return None, f"the patch in front of the hood is black (L {mu[0]:.0f} < {MIN_SEED_L}): nothing to tell road from"
    cov = np.cov((px - mu).T) + np.diag(np.square(MIN_STD_LAB))
    d = lab.reshape(-1, 3) - mu
    mahal = np.sqrt(np.einsum("ij,jk,ik->i", d, np.linalg.inv(cov), d)).reshape(h, w)
    texture = _texture(lab[..., 0])
    tex_max = max(3.0, 2.0 * float(np.percentile(texture[seed], 90)))
    # painted markings (thin bright or yellow stripes) are road too: they must not cut the
    # oncoming lane off the seed's lane
    kern = cv2.getStructuringElement(cv2.MORPH_RECT, (15, 1))
    paint = (cv2.morphologyEx(lab[..., 0], cv2.MORPH_TOPHAT, kern) > 20) | \
        (cv2.morphologyEx(lab[..., 2], cv2.MORPH_TOPHAT, kern) > 8)
    cand = allowed & (((mahal < MAX_MAHAL) & (texture < tex_max)) | paint)
    cand = cv2.morphologyEx(cand.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8)) > 0
    n, lab_cc = cv2.connectedComponents(cand.astype(np.uint8), connectivity=4)
    keep = np.unique(lab_cc[seed & cand])
    keep = keep[keep > 0]
    if len(keep) == 0:
        return None, "the seed patch in front of the hood does not look like road (no connected region)"
    road = np.isin(lab_cc, keep)
    # lane markings and small holes: fill between the road's edges in every row
    any_row = road.any(axis=1)
    left = np.where(any_row, road.argmax(axis=1), w)
    right = np.where(any_row, w - 1 - road[:, ::-1].argmax(axis=1), -1)
    cols_i = np.arange(w)[None, :]
    road = (cols_i >= left[:, None]) & (cols_i <= right[:, None]) & allowed
    road = cv2.morphologyEx(road.astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8)) > 0
    return cv2.resize(road.astype(np.uint8), (W, H), interpolation=cv2.INTER_NEAREST) > 0, \
        f"colour model seeded at rows {int(free.max() / s)} and above ({int(seed.sum())} px)"


def bands(road: np.ndarray, camera: Camera, T_world_cam: np.ndarray, blocked: np.ndarray) -> np.ndarray:
    """Ground beside the road, up to BAND_M metres to either side in every row (bool HxW)."""
    H, W = road.shape
    out = np.zeros_like(road)
    rows = np.flatnonzero(road.any(axis=1))
    if len(rows) == 0:
        return out
    left = road[rows].argmax(axis=1)
    right = W - 1 - road[rows, ::-1].argmax(axis=1)
    # pixels per metre across the road at each row: two ground points 1 m apart at that depth
    g = to_ground(camera, T_world_cam, np.column_stack([np.full(len(rows), camera.cx), rows]))
    T = np.asarray(T_world_cam)
    depth = np.linalg.norm(g - T[:2, 3], axis=1)
    ppm = np.where(np.isfinite(depth), camera.fx / np.maximum(depth, 0.5), 0.0)
    width = np.minimum(BAND_M * ppm, W).astype(int)
    for r, a, b, bw in zip(rows, left, right, width):
        out[r, max(0, a - bw):a] = True
        out[r, b + 1:min(W, b + 1 + bw)] = True
    return out & ~road & ~blocked


def _texture(L: np.ndarray) -> np.ndarray:
    """Local standard deviation of lightness in a 5x5 window."""
    return np.sqrt(np.maximum(cv2.blur(L * L, (5, 5)) - cv2.blur(L, (5, 5)) ** 2, 0))


def walkable(image: np.ndarray, band: np.ndarray, road: np.ndarray) -> tuple[np.ndarray, str]:
    """(the band pixels that look like a pavement, bool HxW; how many)."""
    H, W = image.shape[:2]
    if not band.any() or not road.any():
        return np.zeros((H, W), bool), "no band beside the road"
    s = WORK_W / W
    h = int(round(H * s))
    small = cv2.resize(image, (WORK_W, h), interpolation=cv2.INTER_AREA)
    lab = cv2.cvtColor(cv2.GaussianBlur(small, (5, 5), 0), cv2.COLOR_BGR2LAB).astype(np.float32)
    b = cv2.resize(band.astype(np.uint8), (WORK_W, h), interpolation=cv2.INTER_NEAREST) > 0
    r = cv2.resize(road.astype(np.uint8), (WORK_W, h), interpolation=cv2.INTER_NEAREST) > 0
    if not r.any():
        return np.zeros((H, W), bool), "the road is too small to compare the band with"
    L = lab[..., 0]
    tex = _texture(L)
    l_road = L[r]
    l0 = float(np.median(l_road))
    # the asphalt's own lightness spread (robust: headlight glare at night is in it)
    step = max(WALK_MIN_DL, 1.5 * 1.4826 * float(np.median(np.abs(l_road - l0))))
    chroma = np.linalg.norm(lab[..., 1:] - np.median(lab[r][:, 1:], axis=0), axis=-1)
    smooth = tex < max(6.0, 2.0 * float(np.percentile(tex[r], 75)))
    walk = b & (chroma < WALK_MAX_CHROMA) & smooth & (np.abs(L - l0) > step)
    walk = cv2.morphologyEx(walk.astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    n, cc, st, _ = cv2.connectedComponentsWithStats(walk, connectivity=4)
    keep = np.zeros(n, bool)
    keep[1:] = st[1:, cv2.CC_STAT_AREA] >= WALK_MIN_AREA * WORK_W * h
    walk = keep[cc]
    frac = float(walk.mean()) / max(float(b.mean()), 1e-9)
    how = (f"{frac:.0%} of the band looks like a pavement (road chroma, smooth, lightness step > {step:.0f})"
           if walk.any() else "nothing beside the road looks like a pavement (grass, gravel, barrier or "
                              "asphalt shoulder): no pedestrians beside this road")
    return cv2.resize(walk.astype(np.uint8), (W, H), interpolation=cv2.INTER_NEAREST) > 0, how


def road_direction(image: np.ndarray, road: np.ndarray | None, camera: Camera, T_world_cam: np.ndarray,
                   horizon) -> tuple[float | None, str]:
    """(road yaw relative to the camera heading in degrees, left > 0; how it was found)."""
    if horizon is None:
        return None, "no horizon"
    H, W = image.shape[:2]
    gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    region = np.zeros((H, W), np.uint8)
    if road is not None:
        region = cv2.dilate(road.astype(np.uint8), np.ones((15, 15), np.uint8))
    else:
        region[int(max(horizon[0][1], horizon[1][1])):] = 1
    edges = cv2.Canny(gray, 60, 160) * region
    segs = cv2.HoughLinesP(edges, 1, np.pi / 180, 40, minLineLength=max(20, W // 30), maxLineGap=8)
    u_vp = []
    if segs is not None:
        (hu0, hv0), (hu1, hv1) = horizon
        for x0, y0, x1, y1 in segs[:, 0].astype(float):
            ang = abs(math.degrees(math.atan2(y1 - y0, x1 - x0))) % 180
            if not 20 <= min(ang, 180 - ang) <= 80:
                continue  # nearly flat or vertical: not a line along the road
            # intersect the segment's line with the horizon line
            a1, b1 = y1 - y0, x0 - x1
            a2, b2 = hv1 - hv0, hu0 - hu1
            det = a1 * b2 - a2 * b1
            if abs(det) < 1e-9:
                continue
            c1, c2 = a1 * x0 + b1 * y0, a2 * hu0 + b2 * hv0
            u = (c1 * b2 - c2 * b1) / det
            if -W <= u <= 2 * W:
                u_vp.append(u)
    if len(u_vp) >= 2:
        # lines on either side of the road meet at the vanishing point: take the densest u
        u_vp = np.sort(np.asarray(u_vp))
        k = max(2, len(u_vp) // 3)
        spans = u_vp[k - 1:] - u_vp[:len(u_vp) - k + 1]
        i = int(np.argmin(spans))
        u = float(np.median(u_vp[i:i + k]))
        how = f"vanishing point of {k} of {len(u_vp)} road lines at u = {u:.0f}"
    elif road is not None and road.any():
        rows = np.flatnonzero(road.any(axis=1))
        left = road[rows].argmax(axis=1)
        right = W - 1 - road[rows, ::-1].argmax(axis=1)
        ok = (left > 0) & (right < W - 1)
        if ok.sum() < 5:
            return None, "no road lines and the road's edges leave the image"
        b, a = np.polyfit(rows[ok], (left[ok] + right[ok]) / 2, 1)
        u = float(a + b * horizon_v(horizon, camera.cx))
        how = f"centreline of the road mask meets the horizon at u = {u:.0f}"
    else:
        return None, "no road lines and no road region"
    v = float(horizon_v(horizon, u))
    ray = rays_world(camera, T_world_cam, [[u, v]])[0]
    T = np.asarray(T_world_cam)
    heading = math.atan2(T[1, 2], T[0, 2])
    yaw = math.degrees(math.atan2(ray[1], ray[0]) - heading)
    yaw = (yaw + 180) % 360 - 180
    if abs(yaw) > MAX_ROAD_YAW_DEG:
        return None, f"{how}: {yaw:.1f} deg is beyond +-{MAX_ROAD_YAW_DEG:g} deg, not trusted"
    return yaw, how


CL_WORK_W = 640         # the centre-line search runs at this width (yellow stripes are a few px wide)
CL_RANGE_M = (4.0, 40.0)
CL_MIN_B = 4.0          # OpenCV Lab b* above the asphalt's (and the white paint's) and the row around it: yellow paint
CL_WHITE_TOPHAT_L = 20.0  # Lab L* above the row around it: a painted stripe
ACROSS = cv2.getStructuringElement(cv2.MORPH_RECT, (25, 1))  # top-hats across the row: thin stripes
EL_RANGE_M = (6.0, 24.0)  # where a right edge line is looked for (resolved, not hidden by the hood)
EL_MIN_COVER = 0.8      # of its 1 m steps painted: a solid line (a dashed one: ~0.25-0.4)
CL_MIN_PX = 40
CL_MIN_SPAN_M = 8.0     # along the road: a line, not a yellow car or sign
CL_MAX_SPREAD_M = 0.35  # robust lateral spread of the stripe's pixels
CL_MIN_BEYOND_M = {"double": 1.5, "single": 2.2}  # road beyond it: oncoming lane, not a highway's left shoulder
CL_DOUBLE_SHARE = 0.3


def centre_line(image: np.ndarray, road: np.ndarray | None, camera: Camera, T_world_cam: np.ndarray,
                horizon) -> tuple[float | None, str]:
    """(lateral offset in metres, left of the camera > 0, of a yellow line that divides the
    traffic directions, or None; how it was decided).

    North American roads paint the line between opposing directions yellow; a divided
    highway paints its left edge yellow too, with no lane beyond it. So the line counts only
    with at least a lane's width of road beyond it. White centre lines (most of Europe) are
    not told apart from lane lines: the directions are then left to the user."""
    if road is None or not road.any():
        return None, "no road region"
    lab, r, s = _work_lab(image, road)
    b = lab[..., 2]
    b_road = float(np.median(b[r]))
    cam = np.asarray(T_world_cam)[:2, 3]
    # thin yellow stripes: b* above the asphalt and above its own neighbourhood across the row,
    # and above the white paint's (the median b* of the painted stripes right of the camera,
    # which North America paints white): bluish asphalt makes white lines read 6-8 above it
    # (real highway video), where yellow paint reads 17-33 above
    pv, pu, px, py = _painted(lab, r, camera, T_world_cam, s)
    right = (px > CL_RANGE_M[0]) & (px < CL_RANGE_M[1]) & (py < -0.5)
    white = float(np.median(b[pv[right], pu[right]])) - b_road if right.sum() >= CL_MIN_PX else -np.inf
    min_b = CL_MIN_B + max(white, 0.0)
    tophat = cv2.morphologyEx(b, cv2.MORPH_TOPHAT, ACROSS)
    yellow = r & (b - b_road > min_b) & (tophat > CL_MIN_B) & (lab[..., 1] < 128 + 25) & (lab[..., 0] < 245)
    v, u = np.nonzero(yellow)
    if len(u) < CL_MIN_PX:
        paint = f"; white paint reads {white:+.0f} b* above the asphalt" if white > 0 else ""
        return None, f"no yellow road line ({len(u)} px{paint})"
    g = to_ground(camera, T_world_cam, np.column_stack([u, v]) / s)
    x, y = g[:, 0] - cam[0], g[:, 1] - cam[1]
    ok = np.isfinite(x) & (x > CL_RANGE_M[0]) & (x < CL_RANGE_M[1])
    if ok.sum() < CL_MIN_PX:
        return None, f"no yellow road line between {CL_RANGE_M[0]:g} and {CL_RANGE_M[1]:g} m ({int(ok.sum())} px)"
    x, y, u, v = x[ok], y[ok], u[ok], v[ok]
    # the densest 0.5 m of lateral offsets: the stripe (or the pair of a double line)
    ys = np.sort(y)
    k = np.searchsorted(ys, ys + 0.5, side="right") - np.arange(len(ys))
    y0 = float(np.median(ys[int(np.argmax(k)):int(np.argmax(k)) + int(k.max())]))
    on = np.abs(y - y0) < 0.5
    spread = 1.4826 * float(np.median(np.abs(y[on] - y0)))
    span = float(np.ptp(x[on])) if on.any() else 0.0
    if on.sum() < CL_MIN_PX or span < CL_MIN_SPAN_M or spread > CL_MAX_SPREAD_M:
        return None, (f"yellow pixels at y = {y0:+.1f} m do not form a line along the road "
                      f"({int(on.sum())} px over {span:.0f} m, spread {spread:.2f} m)")
    if y0 <= 0.5:
        return None, f"the yellow line is at y = {y0:+.1f} m, not left of the ego lane"
    double = _double_rows(yellow, u[on], v[on], y[on])
    # road beyond the line: the road mask's left edge in the line's rows, on the ground
    rows = np.unique(v[on])
    left_u = r[rows].argmax(axis=1)
    edge = to_ground(camera, T_world_cam, np.column_stack([left_u, rows]) / s)[:, 1] - cam[1]
    # parked cars and the image border cut the far side in many rows: its widest part counts
    beyond = float(np.nanpercentile(edge, 90)) - y0 if np.isfinite(edge).any() else float("nan")
    kind = "double" if double >= CL_DOUBLE_SHARE else "single"
    need = CL_MIN_BEYOND_M[kind]
    if not np.isfinite(beyond) or beyond < need:
        return None, (f"{kind} yellow line at y = {y0:+.1f} m with {beyond:.1f} m of road beyond it "
                      f"(< {need:g} m; {double:.0%} of rows double): the road's left edge (one-way or divided), not a centre line")
    return y0, (f"{kind} yellow centre line at {y0:+.1f} m left ({int(on.sum())} px over {span:.0f} m, "
                         f"{double:.0%} of its rows double), {beyond:.1f} m of road beyond it: traffic there "
                         f"comes towards the camera")


def edge_line(image: np.ndarray, road: np.ndarray | None, camera: Camera, T_world_cam: np.ndarray
              ) -> tuple[float | None, str]:
    """(lateral offset in metres, < 0, of the solid line nearest the camera on its right, or
    None; how it was decided). A freeway's right edge line: beyond it is the shoulder, where
    traffic does not drive. Painted stripes (thin, brighter than the row around them) on the
    road between EL_RANGE_M are put on the ground and grouped by lateral offset; a group is a
    solid line when it covers EL_MIN_COVER of the range's 1 m steps (a dashed lane line: 3 m of
    paint in 12 m, a quarter)."""
    if road is None or not road.any():
        return None, "no road region"
    lab, r, s = _work_lab(image, road)
    _, _, x, y = _painted(lab, r, camera, T_world_cam, s)
    ok = (x > EL_RANGE_M[0]) & (x < EL_RANGE_M[1]) & (y < -0.5) & (y > -8.0)
    x, y = x[ok], y[ok]
    steps = int(EL_RANGE_M[1] - EL_RANGE_M[0])
    found = []
    # lateral bins 0.25 m apart, each with its neighbours (a line's pixels spread over ~0.2 m)
    for y0 in np.arange(-7.875, -0.5, 0.25):
        on = np.abs(y - y0) < 0.25
        if on.sum() < CL_MIN_PX:
            continue
        cover = len(np.unique(np.floor(x[on] - EL_RANGE_M[0]).astype(int))) / steps
        if cover >= EL_MIN_COVER:
            found.append((float(np.median(y[on])), cover))
    if not found:
        return None, f"no solid line right of the camera between {EL_RANGE_M[0]:g} and {EL_RANGE_M[1]:g} m"
    y0, cover = max(found)
    return y0, f"solid line at {y0:+.1f} m ({cover:.0%} of {EL_RANGE_M[0]:g}-{EL_RANGE_M[1]:g} m painted)"


def _work_lab(image: np.ndarray, road: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """The frame at CL_WORK_W wide in Lab (float32), the road mask at that size, the scale."""
    H, W = image.shape[:2]
    s = CL_WORK_W / W
    size = (CL_WORK_W, int(round(H * s)))
    lab = cv2.cvtColor(cv2.resize(image, size, interpolation=cv2.INTER_AREA), cv2.COLOR_BGR2LAB).astype(np.float32)
    return lab, cv2.resize(road.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0, s


def _painted(lab: np.ndarray, road: np.ndarray, camera: Camera, T_world_cam: np.ndarray, s: float):
    """Painted stripes on the road (thin, L* CL_WHITE_TOPHAT_L above the row around them; the
    road mask's border counts, an edge line often is it): their work-image pixels (v, u) and
    ground offsets from the camera (x ahead, y left), those with a ground point only."""
    r = cv2.dilate(road.astype(np.uint8), np.ones((1, 5), np.uint8)) > 0
    v, u = np.nonzero(r & (cv2.morphologyEx(lab[..., 0], cv2.MORPH_TOPHAT, ACROSS) > CL_WHITE_TOPHAT_L))
    g = to_ground(camera, T_world_cam, np.column_stack([u, v]) / s) if len(u) else np.zeros((0, 2))
    ok = np.isfinite(g[:, 0])
    cam = np.asarray(T_world_cam)[:2, 3]
    return v[ok], u[ok], g[ok, 0] - cam[0], g[ok, 1] - cam[1]


def _double_rows(yellow: np.ndarray, u: np.ndarray, v: np.ndarray, y: np.ndarray) -> float:
    """Share of the line's rows (near the camera, where a pair is resolved) that hold two
    yellow runs: a double line, which only ever divides the two directions."""
    rows = np.unique(v)
    rows = rows[rows >= np.percentile(rows, 50)]   # the nearer half
    n2 = 0
    for r in rows:
        cols = np.sort(u[v == r])
        runs = 1 + int(np.sum(np.diff(cols) > 1)) if len(cols) else 0
        n2 += runs == 2
    return n2 / max(len(rows), 1)
