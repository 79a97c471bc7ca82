"""The object catalog (bpy-free): a seeded sampler of builder parameters and real-world
dimensions per class, so the planner knows each object's box before Blender builds it.

Target sizes are drawn from typical European/North-American ranges per body type
(`blendgen.dimensions`); the returned dims (length x, width y, height z; metres) are the
tight box of the geometry that `assets_procedural.shapes` (NumPy, bpy-free) builds for the
variant, and `assets_procedural.objects.build_object` builds exactly that geometry in Blender.
"""

from __future__ import annotations

import json

import numpy as np

from blendgen import CLASSES
from blendgen.dimensions import BUS_BODIES, CAR_BODIES, TRUCK_BODIES

# most box bodies and trailers are plain white or aluminium; liveries are a minority
CARGO_WEIGHTS = {"white": 0.55, "silver": 0.2, "red": 0.08, "blue": 0.08, "yellow": 0.09}
CAR_PAINTS = {  # linear RGB, roughly the world's car-colour mix
    "white": (0.80, 0.80, 0.78), "black": (0.012, 0.012, 0.014), "silver": (0.50, 0.51, 0.53),
    "grey": (0.16, 0.17, 0.18), "blue": (0.02, 0.06, 0.25), "red": (0.45, 0.02, 0.02),
    "green": (0.02, 0.12, 0.05), "beige": (0.55, 0.45, 0.30), "yellow": (0.75, 0.50, 0.02),
}
# shares of new cars worldwide (Axalta colour report 2022): ~80 % white, black, grey or silver
PAINT_WEIGHTS = {"white": 0.31, "black": 0.20, "silver": 0.12, "grey": 0.18, "blue": 0.07, "red": 0.07,
                 "green": 0.02, "beige": 0.02, "yellow": 0.01}
BUS_LIVERIES = [(0.75, 0.55, 0.02), (0.60, 0.02, 0.02), (0.03, 0.20, 0.45), (0.02, 0.30, 0.10),
                (0.80, 0.80, 0.78)]
# What people wear in the street is mostly dark and neutral (linear albedo, weight): a uniform
# draw over eleven colours, half of them saturated, read as mannequins on real photos.
TOPS = {(0.012, 0.012, 0.014): 0.26, (0.70, 0.70, 0.68): 0.12, (0.18, 0.18, 0.19): 0.14,
        (0.020, 0.030, 0.080): 0.12, (0.40, 0.33, 0.22): 0.07, (0.10, 0.07, 0.045): 0.06,
        (0.03, 0.07, 0.035): 0.05, (0.20, 0.02, 0.03): 0.05, (0.05, 0.14, 0.30): 0.05,
        (0.45, 0.05, 0.04): 0.04, (0.55, 0.30, 0.02): 0.02, (0.45, 0.15, 0.25): 0.02}
PANTS = {(0.012, 0.012, 0.014): 0.34, (0.05, 0.08, 0.16): 0.30, (0.10, 0.10, 0.11): 0.12,
         (0.33, 0.27, 0.17): 0.10, (0.018, 0.025, 0.06): 0.08, (0.08, 0.055, 0.035): 0.06}
# Tan and brown clothes near a skin tone: a top and trousers both from here read as a bare
# mannequin on real photos (a rider in brown on the BDD snow street, in khaki on the freeway)
SKIN_LIKE = {(0.40, 0.33, 0.22), (0.10, 0.07, 0.045), (0.33, 0.27, 0.17), (0.08, 0.055, 0.035)}
# What motorcyclists wear over it: riding jackets, mostly black (linear albedo, weight)
RIDER_JACKETS = {(0.012, 0.012, 0.014): 0.45, (0.10, 0.10, 0.11): 0.15, (0.020, 0.030, 0.080): 0.10,
                 (0.10, 0.07, 0.045): 0.08, (0.70, 0.70, 0.68): 0.06, (0.45, 0.05, 0.04): 0.06,
                 (0.55, 0.60, 0.02): 0.05, (0.03, 0.07, 0.035): 0.05}
# Helmets are mostly black, white or grey, whatever the two-wheeler's colour: one in a beige
# scooter's paint read as a bare head on the BDD snow street
HELMETS = {(0.012, 0.012, 0.014): 0.45, (0.75, 0.75, 0.73): 0.20, (0.25, 0.25, 0.26): 0.15,
           (0.45, 0.03, 0.03): 0.07, (0.03, 0.08, 0.30): 0.07, (0.55, 0.55, 0.56): 0.06}
SHOES = {(0.012, 0.012, 0.014): 0.5, (0.65, 0.65, 0.63): 0.25, (0.10, 0.07, 0.045): 0.15, (0.18, 0.18, 0.19): 0.1}
SKIN = [(0.75, 0.55, 0.42), (0.62, 0.42, 0.30), (0.45, 0.28, 0.18), (0.28, 0.16, 0.10), (0.82, 0.64, 0.52)]
HAIR = [(0.02, 0.015, 0.01), (0.12, 0.06, 0.03), (0.35, 0.22, 0.10), (0.55, 0.45, 0.30), (0.4, 0.4, 0.4)]

# plausible speeds (m/s) when moving
SPEED = {"person": (0.9, 1.7), "bicycle": (3.5, 6.5), "car": (6.0, 14.0), "motorcycle": (7.0, 15.0),
         "bus": (5.0, 11.0), "truck": (5.0, 12.0), "traffic light": (0.0, 0.0)}


def _u(rng, lo_hi) -> float:
    return float(rng.uniform(*lo_hi))


def _jitter(rng, rgb, amount=0.06):
    return [float(np.clip(c * (1 + rng.uniform(-amount, amount)), 0, 1)) for c in rgb]


def _pick(rng, seq):
    return seq[int(rng.integers(len(seq)))]


def _weighted(rng, table: dict):
    """A key of `table` drawn with its weight."""
    keys = list(table)
    w = np.array(list(table.values()), float)
    return keys[int(rng.choice(len(keys), p=w / w.sum()))]


def _person(rng, *, height=None, pose=None, tops=TOPS) -> tuple[dict, tuple]:
    h = float(height if height is not None else np.clip(rng.normal(1.71, 0.09), 1.50, 1.95))
    build = _pick(rng, ["slim", "medium", "broad"])
    shoulder = {"slim": 0.23, "medium": 0.25, "broad": 0.28}[build] * h  # shoulder breadth
    pose = pose or _pick(rng, ["standing", "walking", "walking"])
    stride = _u(rng, (0.2, 0.38)) if pose == "walking" else 0.0  # hip swing (rad)
    leg = 0.47 * h
    depth = max(0.28 * h / 1.75, 2 * leg * np.sin(stride) + 0.26)
    width = shoulder + 0.12 * h / 1.75
    top = _weighted(rng, tops)
    pants = {c: w for c, w in PANTS.items() if top not in SKIN_LIKE or c not in SKIN_LIKE}
    v = {"kind": pose, "build": build, "stride_rad": stride, "skin": _pick(rng, SKIN),
         "hair": _pick(rng, HAIR), "shirt": _jitter(rng, top),
         "pants": _jitter(rng, _weighted(rng, pants)), "shoes": _jitter(rng, _weighted(rng, SHOES)),
         "long_sleeves": bool(rng.random() < 0.6), "skirt": bool(rng.random() < 0.12),
         "bag": bool(rng.random() < 0.3), "height_m": h}
    return v, (float(depth), float(width), h)


def helmet_colour(two_wheeler: dict) -> tuple[float, float, float]:
    """A rider's helmet colour, from the two-wheeler variant's seed (no draw from the planner's
    stream: plans keep their draws)."""
    return _weighted(np.random.default_rng(int(two_wheeler.get("seed", 0)) + 1), HELMETS)


def sample_variant(cls: str, rng: np.random.Generator) -> tuple[dict, tuple[float, float, float]]:
    """(builder parameters, dims) of a random instance of `cls`."""
    if cls not in CLASSES:
        raise ValueError(f"unknown class {cls!r}; expected one of {sorted(CLASSES)}")
    seed = int(rng.integers(2**31))
    if cls == "car":
        kind = _pick(rng, list(CAR_BODIES))
        L, W, H = (_u(rng, r) for r in CAR_BODIES[kind])
        paint = str(_weighted(rng, PAINT_WEIGHTS))
        v = {"kind": kind, "paint": _jitter(rng, CAR_PAINTS[paint], 0.08), "paint_name": paint,
             "wheel_radius": _u(rng, (0.31, 0.36)), "chrome_trim": bool(rng.random() < 0.4)}
    elif cls == "truck":
        kind = _pick(rng, list(TRUCK_BODIES))
        L, W, H = (_u(rng, r) for r in TRUCK_BODIES[kind])
        v = {"kind": kind, "paint": _jitter(rng, _pick(rng, list(CAR_PAINTS.values()))),
             "cargo": _jitter(rng, CAR_PAINTS[_weighted(rng, CARGO_WEIGHTS)]),
             "wheel_radius": 0.33 if kind == "pickup" else 0.5}
    elif cls == "bus":
        kind = _pick(rng, list(BUS_BODIES))
        L, W, H = (_u(rng, r) for r in BUS_BODIES[kind])
        v = {"kind": kind, "paint": _jitter(rng, _pick(rng, BUS_LIVERIES)), "wheel_radius": 0.5,
             "doors": 3 if kind == "city" else 2}
    elif cls == "person":
        v, (L, W, H) = _person(rng)
    elif cls in ("bicycle", "motorcycle"):
        if cls == "bicycle":
            kind = _pick(rng, ["city", "road", "mountain"])
            wheel = {"city": 0.35, "road": 0.34, "mountain": 0.36}[kind]
            L, W, H = _u(rng, (1.68, 1.82)), _u(rng, (0.56, 0.66)), _u(rng, (0.98, 1.10))
            rider_p = 0.7
        else:
            kind = _pick(rng, ["sport", "cruiser", "scooter"])
            wheel = {"sport": 0.31, "cruiser": 0.33, "scooter": 0.24}[kind]
            L = _u(rng, {"sport": (2.0, 2.15), "cruiser": (2.2, 2.4), "scooter": (1.75, 1.95)}[kind])
            W, H = _u(rng, (0.72, 0.90)), _u(rng, (1.10, 1.30))
            rider_p = 0.8
        v = {"kind": kind, "paint": _jitter(rng, _pick(rng, list(CAR_PAINTS.values()))), "wheel_radius": wheel}
        if rng.random() < rider_p:
            rv, _ = _person(rng, pose="riding", tops=RIDER_JACKETS if cls == "motorcycle" else TOPS)
            rv["helmet"] = bool(cls == "motorcycle" or rng.random() < 0.5)
            if cls == "motorcycle":  # sport riders wear full-face helmets, others half helmets
                rv["helmet_kind"] = "full_face" if kind == "sport" else "half"
                rv.update(long_sleeves=True, skirt=False)  # a jacket or shirt, trousers
            v["rider"] = rv
            # the seated rider raises the top of the box to about 0.80-0.85 of their height
            H = max(H, rv["height_m"] * (0.83 if cls == "bicycle" else 0.78) + (0.55 if cls == "bicycle" else 0.45) * 0.5)
            W = max(W, 0.32 * rv["height_m"] / 1.0 * 0.9)
    else:  # traffic light: the signal head; the pole below it is scenery (pass_index 0)
        kind = _pick(rng, ["visor", "visor", "backplate"])
        L = _u(rng, (0.30, 0.42))
        W = _u(rng, (0.30, 0.36)) + (0.18 if kind == "backplate" else 0.0)
        H = _u(rng, (0.95, 1.10)) + (0.14 if kind == "backplate" else 0.0)
        v = {"kind": kind, "housing": _pick(rng, [(0.02, 0.02, 0.02), (0.03, 0.05, 0.03), (0.5, 0.42, 0.05)]),
             "mount_height_m": _u(rng, (2.4, 3.0))}
    v["seed"] = seed
    # The builder proportions the shape from these target dims; the object's dims are the
    # tight box of exactly that geometry (NumPy only, no bpy), so the render-time fit is 1:1.
    v["shape_dims"] = [round(float(L), 4), round(float(W), 4), round(float(H), 4)]
    v = json.loads(json.dumps(v))  # plain JSON data (lists, not tuples): plans round-trip exactly
    return v, shape_extent(cls, v)


def shape_extent(cls: str, variant: dict) -> tuple[float, float, float]:
    """Tight box (L, W, H) of the geometry `assets_procedural.shapes` builds for a variant."""
    from assets_procedural.shapes import part_box

    lo, hi = part_box(cls, variant)
    return tuple(round(float(x), 4) for x in hi - lo)

