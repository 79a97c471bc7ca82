"""Geometry of the seven object classes (NumPy only, no bpy).

Each builder adds named-material parts to a MeshBuilder in the object frame (x forward,
y left, z up, origin at the centre of the bottom face), shaped from the catalog variant and
the target dims. `fit_to_dims` then maps the tight box exactly onto `dims`; builders are
proportioned so that this correction stays within a few per cent.
Material slot names: paint, glass, rubber, chrome, alloy, plastic, lamp_head, lamp_tail,
lamp_red/amber/green (+ _off), skin, hair, shirt, pants, shoes, bag, helmet, visor, cargo, saddle,
housing, tape_red, tape_white (retroreflective tape), plate, plate_text (its characters).
"""

from __future__ import annotations

import functools
import json
import math

import numpy as np

from assets_procedural import body
from assets_procedural.meshkit import (MeshBuilder, box, cylinder, ellipsoid, grid, loft, rot_x, rot_y,
                                       rounded_section, rounded_section_half_width, torus, tube, xf)


# ====================================================================== vehicles (4 wheels)
def _wheel(mb, x, y, r, width, rim="alloy", spokes=5):
    """Tyre with a spoked rim and dark hub; the outer face at y + side * width / 2. Between a
    car's spokes the dark brake and well show (a plain light disc read as a hubcap); `spokes`
    0: a truck's or bus's steel disc."""
    side = 1 if y > 0 else -1
    v, f = cylinder(r, width, 24, "y", (x, y, r))
    mb.add(v, f, "rubber", smooth=True)
    face = y + side * (width / 2 - 0.004)  # the rim's outer plane
    if not spokes:
        v, f = cylinder(r * 0.66, 0.02, 20, "y", (x, face, r))
        mb.add(v, f, rim)
        v, f = cylinder(r * 0.2, 0.02, 10, "y", (x, y + side * (width / 2 + 0.002), r))
        mb.add(v, f, "plastic")
        return
    v, f = cylinder(r * 0.66, 0.02, 20, "y", (x, face - side * 0.008, r))  # 8 mm behind the spokes
    mb.add(v, f, "well")
    v, f = torus(r * 0.62, r * 0.045, (x, face, r), "y", nu=24, nv=6)  # the rim's lip
    mb.add(v, f, rim, smooth=True)
    for k in range(spokes):
        a = x * 7.3 + 2 * math.pi * k / spokes  # the wheels of one car do not turn in step
        vv, f = box((r * 0.44, 0.02, r * 0.15))
        mb.add(xf(vv, rot_y(a), (x + r * 0.39 * math.cos(a), face, r - r * 0.39 * math.sin(a))), f, rim)
    v, f = cylinder(r * 0.2, 0.02, 10, "y", (x, face, r))
    mb.add(v, f, rim)
    v, f = cylinder(r * 0.08, 0.02, 8, "y", (x, face + side * 0.004, r))
    mb.add(v, f, "plastic")


def _arch(mb, x, y_face, r, side, band=0.07, n=12):
    """Black wheel-arch trim (half ring) and the dark wheel well behind the tyre, on the body side."""
    a = np.linspace(0.0, math.pi, n)
    outer = np.column_stack([x + (r + band) * np.cos(a), (r + band) * np.sin(a)])
    inner = np.column_stack([x + (r + 0.015) * np.cos(a), (r + 0.015) * np.sin(a)])
    yz = y_face + side * 0.006
    v = [[px, yz, pz + r] for px, pz in outer] + [[px, yz, pz + r] for px, pz in inner]
    f = [[i, i + 1, n + i + 1, n + i] for i in range(n - 1)]
    mb.add(v, f, "plastic")
    v, f = cylinder(r + 0.015, 0.01, 16, "y", (x, y_face + side * 0.002, r))
    mb.add(v, f, "well")


def _lower_body(hw, tops, r=0.12):
    """Loft of the lower body from rear (x=-L/2) to front; `tops` = [(x, z_top, width_frac,
    z_bottom)]; `r` the corner radius of the cross-section."""
    return loft([(x, rounded_section(hw * wf, zb, zt, r, top_half_w=hw * wf * 0.96)) for x, zt, wf, zb in tops])


def _body_half_width(tops, hw, x, z, r):
    """Half-width of the `_lower_body` loft at (x, z), its stations interpolated linearly."""
    xs = [t[0] for t in tops]
    zt, wf, zb = (np.interp(x, xs, [t[k] for t in tops]) for k in (1, 2, 3))
    return rounded_section_half_width(hw * wf, zb, zt, r, z, top_half_w=hw * wf * 0.96)


CAR_SHAPES = {  # fractions: beltline/hood/deck heights of H; x positions of L; bottom (sills), the
    # rear and front bumpers' lower edges (tail, nose) of H
    "sedan": dict(belt=.63, hood=.58, deck=.66, ws=.20, roof_f=.03, roof_r=-.22, rw=-.36, bot=.13, axle=.30,
                  tail=.22, nose=.15),
    "hatchback": dict(belt=.61, hood=.57, deck=.63, ws=.20, roof_f=.02, roof_r=-.38, rw=-.47, bot=.13, axle=.31,
                      tail=.22, nose=.15),
    "suv": dict(belt=.60, hood=.61, deck=.63, ws=.22, roof_f=.06, roof_r=-.43, rw=-.48, bot=.14, axle=.31,
                tail=.26, nose=.21),
    "van": dict(belt=.52, hood=.46, deck=.54, ws=.40, roof_f=.27, roof_r=-.47, rw=-.495, bot=.11, axle=.33,
                tail=.21, nose=.15),
}


TWO_BOX = ("hatchback", "suv", "van")  # a tailgate: the rear window in its upper part


def car(mb: MeshBuilder, v: dict, L: float, W: float, H: float):
    """A car: lofted body, tapered dark greenhouse under a painted roof, black trim and
    arches, tyres with rims, head/tail lamps, plates and mirrors."""
    p = CAR_SHAPES.get(v.get("kind", "sedan"), CAR_SHAPES["sedan"])
    r = float(v.get("wheel_radius", 0.33))
    hw = W * 0.93 / 2
    belt, hood, deck = p["belt"] * H, p["hood"] * H, p["deck"] * H
    zb = max(p["bot"] * H, r * 0.55)
    x_ws, x_rw = p["ws"] * L, p["rw"] * L
    ax = p["axle"] * L
    # the overhangs rise from the sills to the bumpers' lower edges within 0.25 m of the tyres: a
    # body down to the sills end to end stood on the road from behind, where a real car shows a
    # dark gap under its bumper and its tyres either side
    z_tail, z_nose = max(zb, p["tail"] * H), max(zb, p["nose"] * H)

    def bottom(x, wf):
        rise = np.clip([(-ax - r - x) / 0.25, (x - ax - r) / 0.25], 0, 1)
        return zb + rise[0] * (z_tail - zb) + rise[1] * (z_nose - zb) + (0.05 if wf < 0.97 else 0.0)

    # lower body: rounded tail, shoulder along the belt, sloping hood and rounded nose
    tops = [(-L / 2, deck - 0.14, 0.88), (-L / 2 + 0.015 * L, deck - 0.03, 0.96), (-L / 2 + 0.05 * L, deck, 0.99),
            (x_rw, belt, 1.0), (x_ws, belt, 1.0), (L / 2 - 0.08 * L, hood, 0.99),
            (L / 2 - 0.02 * L, hood - 0.06, 0.95), (L / 2, hood - 0.16, 0.86)]
    tops = [(x, zt, wf, bottom(x, wf)) for x, zt, wf in tops]
    vv, f = _lower_body(hw, tops, r=0.2)
    mb.add(vv, f, "paint", smooth=True)
    # greenhouse: tinted glass tapering inwards (tumblehome), the roof panel painted on top
    zc = belt - 0.04
    roof_hw = hw * 0.72
    cab = [(x_rw, rounded_section(hw * 0.95, zc, belt + 0.02, 0.05, top_half_w=hw * 0.93)),
           (p["roof_r"] * L, rounded_section(hw * 0.93, zc, H - 0.035, 0.12, top_half_w=roof_hw)),
           (p["roof_f"] * L, rounded_section(hw * 0.93, zc, H - 0.035, 0.12, top_half_w=roof_hw)),
           (x_ws, rounded_section(hw * 0.95, zc, belt + 0.02, 0.05, top_half_w=hw * 0.93))]
    # the rear slope painted (C- or D-pillars from the side, a band under the roof) round an
    # inset window; all glass, the back of a hatchback, SUV or van was a tall dark panel that
    # YOLOX-Nano took for a bus's rear on the real highway photos
    vv, f = loft(cab[:2])
    mb.add(vv, f, "paint")
    vv, f = loft(cab[1:])
    mb.add(vv, f, "glass")
    # a tailgate's window keeps to its upper part, a sedan's backlight fills its slope
    z0, z1 = (max(belt + 0.1, 0.64 * H), H - 0.1) if v.get("kind") in TWO_BOX else (belt + 0.05, H - 0.07)
    _rear_window(mb, (x_rw, 0.93 * hw - 0.05, belt + 0.02), (p["roof_r"] * L, roof_hw - 0.12, H - 0.035), z0, z1)
    roof = [(p["roof_r"] * L - 0.03, rounded_section(roof_hw * 1.02, H - 0.06, H, 0.025, top_half_w=roof_hw * 0.97)),
            (p["roof_f"] * L + 0.03, rounded_section(roof_hw * 1.02, H - 0.06, H, 0.025, top_half_w=roof_hw * 0.97))]
    vv, f = loft(roof)
    mb.add(vv, f, "paint", smooth=True)
    # B- and C-pillars in black trim split the side glass into windows: strips on the glass from
    # the belt up, following its tumblehome and rounded top (a straight lean stood out of the
    # painted rear pillars seen from behind, as thin dark lines)
    xb = (p["roof_f"] + p["roof_r"]) / 2 * L
    zs = np.linspace(belt, H - 0.06, 8)
    ys = np.array([rounded_section_half_width(hw * 0.93, zc, H - 0.035, 0.12, z, top_half_w=roof_hw) + 0.004
                   for z in zs])
    for s in (1, -1):
        for xp, wp in ((xb, 0.10), (p["roof_r"] * L + 0.05, 0.07)):
            mb.add(*grid(np.array([[[x, s * y, z] for y, z in zip(ys, zs)] for x in (xp - wp / 2, xp + wp / 2)])),
                   "plastic")
    # wheels in black arches
    for x in (ax, -ax):
        for s in (1, -1):
            _wheel(mb, x, s * (hw - 0.1), r, 0.22, "chrome" if v.get("chrome_trim") else "alloy")
            _arch(mb, x, s * hw, r, s)
    # black sills and bumper bottoms
    for s in (1, -1):
        vv, f = box((2 * ax - 2 * r - 0.2, 0.02, 0.09), (0, s * (hw + 0.004), zb + 0.05))
        mb.add(vv, f, "plastic")
    for x, sgn, ze in ((L / 2 - 0.04, 1, z_nose), (-L / 2 + 0.04, -1, z_tail)):  # 2 cm proud of the body
        # body-coloured covers as narrow as the rounded ends, over a black valance (a full-width
        # black slab read as a toy's bumper on the real photos); an SUV's valance is taller
        lip = 0.13 if v.get("kind") == "suv" else 0.08
        vv, f = box((0.12, hw * 1.74, 0.2), (x, 0, ze + 0.1))
        mb.add(vv, f, "paint")
        vv, f = box((0.118, hw * 1.6, lip), (x + sgn * 0.001, 0, ze + 0.03 - lip / 2))
        mb.add(vv, f, "plastic")
        _plate(mb, (0.02, 0.52, 0.12), (x + sgn * 0.045, 0, ze + 0.27))  # over the cover
    # head lamps and grille on the nose's front face (below the hood line, where the loft's
    # section is upright: higher up they sank into the rounded nose and showed as a speck),
    # tail lamps wrapping round the rear corners
    zl = hood - 0.24
    y_lamp = 0.86 * hw - 0.24
    for s in (1, -1):
        vv, f = box((0.03, 0.30, 0.11), (L / 2 + 0.005, s * y_lamp, zl))
        mb.add(vv, f, "lamp_head")
        _tail_lamp(mb, tops, hw, -L / 2, deck - 0.14, s)
        # mirror on a short arm at the front of the side glass
        vv, f = box((0.10, 0.17, 0.11), (x_ws - 0.14, s * (hw + 0.1), belt + 0.07))
        mb.add(vv, f, "paint")
        vv, f = box((0.01, 0.13, 0.08), (x_ws - 0.195, s * (hw + 0.11), belt + 0.07))
        mb.add(vv, f, "plastic")
    vv, f = box((0.03, 2 * (y_lamp - 0.17), 0.10), (L / 2 + 0.004, 0, zl))  # grille between the lamps
    mb.add(vv, f, "plastic")
    # behind: a dark garnish strip between the tail lamps with a small badge under it, and a
    # high-mounted stop lamp under the roof (a smooth blank tail between two small lamps read as
    # a toy on real photos; a chrome strip mirrored the sky as a second plate)
    vv, f = box((0.03, 2 * (hw - 0.45), 0.06), (-L / 2 + 0.01, 0, deck - 0.12))
    mb.add(vv, f, "plastic")
    vv, f = box((0.02, 0.1, 0.04), (-L / 2 + 0.005, 0, deck - 0.2))
    mb.add(vv, f, "chrome")
    vv, f = box((0.05, 0.3, 0.04), (p["roof_r"] * L - 0.02, 0, H - 0.07))
    mb.add(vv, f, "lamp_tail")


def _tail_lamp(mb, tops, hw, x_rear, z_top, side, height=0.16, width=0.3, wrap=0.15):
    """A tail-lamp cluster hugging the tail's rounded corner: a lens on the rear face whose
    outer edge follows the corner's curve, wrapping `wrap` m round onto the side (boxes there
    stood out of the tapered tail as red ears)."""
    zs = np.linspace(z_top - 0.03 - height, z_top - 0.03, 4)
    edge = np.array([_body_half_width(tops, hw, x_rear, z, 0.2) for z in zs])
    inner = edge.max() - width
    back = np.array([[[x_rear - 0.004, side * y, z] for y, z in zip(ys, zs)]
                     for ys in (np.full(4, inner), edge - 0.004)])
    mb.add(*grid(back), "lamp_tail")
    xs = np.linspace(x_rear, x_rear + wrap, 7)
    round_ = np.array([[[x, side * (_body_half_width(tops, hw, x, z, 0.2) + 0.004), z] for z in zs] for x in xs])
    mb.add(*grid(round_), "lamp_tail")


def _rear_window(mb, bottom, top, z0, z1):
    """An inset glass panel on the greenhouse's painted rear slope, the plane through the
    slope's flat bottom edge (x, half-width, z) and top edge; the glass from height z0 to z1,
    0.82 of the slope's width, 5 mm proud of the paint."""
    b, t = np.asarray(bottom, float), np.asarray(top, float)
    dx, dz = t[0] - b[0], t[2] - b[2]
    n = np.array([-dz, 0.0, dx]) / math.hypot(dx, dz)  # outward, backwards and up
    P = []
    for u in ((z0 - b[2]) / dz, (z1 - b[2]) / dz):
        x, hwu, z = b + u * (t - b)
        P.append([[x, y * 0.82 * hwu, z] + 0.005 * n for y in (-1, 1)])
    mb.add(*grid(np.array(P)), "glass")


# seven-segment digits over segments a-g (top, top right, bottom right, bottom, bottom left,
# top left, middle): from a few metres they read as a plate's characters
_DIGITS = ("abcdef", "bc", "abged", "abgcd", "fgbc", "afgcd", "afgedc", "abc", "abcdefg", "abcdfg")


def _plate(mb, size, centre, facing=-1, R=None, chars=0):
    """A number plate, a box of `size` (x, y, z) turned by R about its centre, with `chars` dark
    characters on its face toward `facing` (-1 backwards, +1 forwards). On a motorcycle's plate
    they count (YOLOX-Nano found 97 -> 104 of 261 motorcycles on the same plans); on cars they
    cost 7 of 127 (close rear views on the highway read as buses, 13 -> 20), so cars, trucks and
    buses keep a plain plate."""
    t, w, h = size
    vv, f = box(size)
    mb.add(xf(vv, R, centre), f, "plate")
    if not chars:
        return
    gh = 0.6 * h
    gw, pitch, th = min(0.6 * gh, 0.75 * w / chars), 0.85 * w / chars, 0.14 * gh
    hx, hz = gw / 2 - th / 2, gh / 2 - th / 2
    seg = {"a": (0, hz, gw, th), "d": (0, -hz, gw, th), "g": (0, 0, gw, th),  # (u, v, width, height)
           "b": (hx, gh / 4, th, gh / 2), "c": (hx, -gh / 4, th, gh / 2),
           "f": (-hx, gh / 4, th, gh / 2), "e": (-hx, -gh / 4, th, gh / 2)}
    rng = np.random.default_rng(int(abs(np.sum(centre)) * 1e4))
    for k, d in enumerate(rng.integers(0, 10, chars)):
        u0 = (k - (chars - 1) / 2) * pitch
        for u, v, sw, sh in (seg[c] for c in _DIGITS[d]):
            # read left to right from outside: behind a vehicle the viewer's right is -y
            vv, f = box((0.002, sw, sh), (facing * (t / 2 + 0.001), facing * (u0 + u), v))
            mb.add(xf(vv, R, centre), f, "plate_text")


def _cab(mb, x_front, length, hw, z0, z1, glass_from):
    """A truck/pickup cab: painted body with windscreen, side windows and a rear window."""
    vv, f = loft([(x_front - length, rounded_section(hw, z0, z1, 0.12)),
                  (x_front - 0.1, rounded_section(hw, z0, z1, 0.12)),
                  (x_front, rounded_section(hw * 0.97, z0 + 0.05, z1 - 0.08, 0.1))])
    mb.add(vv, f, "paint", smooth=True)
    zg = z0 + glass_from * (z1 - z0)
    vv, f = box((0.04, hw * 1.8, (z1 - 0.12) - zg), (x_front + 0.005, 0, (z1 - 0.12 + zg) / 2))
    mb.add(vv, f, "glass")
    # a pickup seen from behind showed a blank painted back above its tailgate
    vv, f = box((0.02, hw * 1.4, (z1 - 0.16) - (zg + 0.08)), (x_front - length - 0.005, 0, (z1 - 0.16 + zg + 0.08) / 2))
    mb.add(vv, f, "glass")
    for s in (1, -1):
        vv, f = box((length * 0.55, 0.03, (z1 - 0.15) - zg), (x_front - length * 0.4, s * (hw + 0.005),
                                                             (z1 - 0.15 + zg) / 2))
        mb.add(vv, f, "glass")
    for s in (1, -1):
        vv, f = box((0.05, 0.28, 0.16), (x_front + 0.01, s * (hw - 0.3), z0 + 0.35))
        mb.add(vv, f, "lamp_head")


def truck(mb: MeshBuilder, v: dict, L: float, W: float, H: float):
    kind = v.get("kind", "box_truck")
    r = float(v.get("wheel_radius", 0.5))
    hw = W / 2
    if kind == "pickup":
        zb = 0.45
        _cab(mb, L / 2 - 1.2, 1.6, hw * 0.98, zb, H, 0.45)
        hood = [(L / 2 - 1.25, rounded_section(hw * 0.98, zb, 0.58 * H, 0.1)),
                (L / 2, rounded_section(hw * 0.94, zb + 0.05, 0.55 * H, 0.1))]
        vv, f = loft(hood)
        mb.add(vv, f, "paint", smooth=True)
        xb0, xb1 = -L / 2 + 0.12, L / 2 - 2.85
        vv, f = box((xb1 - xb0, 2 * hw * 0.98, 0.08), ((xb0 + xb1) / 2, 0, zb + 0.05))
        mb.add(vv, f, "plastic")
        for s in (1, -1):
            vv, f = box((xb1 - xb0, 0.06, 0.5), ((xb0 + xb1) / 2, s * (hw * 0.98 - 0.03), zb + 0.3))
            mb.add(vv, f, "paint")
        vv, f = box((0.06, 2 * hw * 0.98, 0.5), (xb0 + 0.03, 0, zb + 0.3))  # the tailgate
        mb.add(vv, f, "paint")
        vv, f = box((0.02, 0.25, 0.06), (xb0 - 0.005, 0, zb + 0.46))  # its handle
        mb.add(vv, f, "plastic")
        vv, f = box((0.14, 2 * hw * 0.96, 0.16), (-L / 2 + 0.07, 0, zb - 0.02))  # step bumper
        mb.add(vv, f, "chrome")
        _plate(mb, (0.02, 0.52, 0.12), (xb0 - 0.005, 0, zb + 0.16))  # on the tailgate
        axles = [L / 2 - 1.0, -L / 2 + 1.35]
        for s in (1, -1):  # tall lamps in the bed's rear corners
            vv, f = box((0.05, 0.12, 0.34), (xb0 + 0.01, s * (hw * 0.98 - 0.06), zb + 0.36))
            mb.add(vv, f, "lamp_tail")
    else:
        cab_len = 2.2 if kind == "box_truck" else 2.5
        cab_h = (0.78 if kind == "box_truck" else 0.82) * H
        z_ch = r + 0.15
        _cab(mb, L / 2, cab_len, hw * 0.98, z_ch - 0.2, cab_h, 0.5)
        # the cab's face: a grille between the lamps and a bumper (an oncoming truck was a box)
        z_g0, z_g1 = z_ch + 0.2, (z_ch - 0.2 + cab_h) / 2 - 0.12  # up to the windscreen
        vv, f = box((0.02, 2 * hw * 0.98 - 1.0, z_g1 - z_g0), (L / 2 + 0.012, 0, (z_g0 + z_g1) / 2))
        mb.add(vv, f, "well")
        for z in np.linspace(z_g0 + 0.04, z_g1 - 0.04, 6):
            vv, f = box((0.03, 2 * hw * 0.98 - 1.0, 0.03), (L / 2 + 0.02, 0, z))
            mb.add(vv, f, "chrome")
        vv, f = box((0.16, 2 * hw * 0.98, 0.25), (L / 2 - 0.05, 0, z_ch - 0.2))
        mb.add(vv, f, "plastic")
        if kind == "semi":  # roof fairing up to the trailer
            vv, f = loft([(L / 2 - cab_len, rounded_section(hw * 0.95, cab_h - 0.05, H - 0.05, 0.2)),
                          (L / 2 - cab_len * 0.35, rounded_section(hw * 0.85, cab_h - 0.05, cab_h + 0.05, 0.05))])
            mb.add(vv, f, "paint", smooth=True)
        gap = 0.15 if kind == "box_truck" else 0.6
        x1 = L / 2 - cab_len - gap
        z_box = z_ch + (0.15 if kind == "box_truck" else 0.45)
        vv, f = loft([(-L / 2, rounded_section(hw, z_box, H, 0.05)), (x1, rounded_section(hw, z_box, H, 0.05))])
        mb.add(vv, f, "cargo")
        vv, f = box((L - 0.4, 1.0, 0.3), (0.1, 0, z_ch))
        mb.add(vv, f, "plastic")
        if kind == "box_truck":
            axles = [L / 2 - 1.3, -L / 2 + 1.7]
        else:
            axles = [L / 2 - 1.3, L / 2 - 4.2, L / 2 - 5.5, -L / 2 + 1.2, -L / 2 + 2.5, -L / 2 + 3.8]
        _box_rear(mb, -L / 2, hw, z_box, H)
    for x in axles:
        for s in (1, -1):
            _wheel(mb, x, s * (hw - 0.17), r, 0.32, "alloy", spokes=0)


def _box_rear(mb, x, hw, z0, z1):
    """The rear of a cargo box, the view a dashcam has of most trucks (a plain coloured box read
    as a toy on real photos): two doors with hinges and locking bars in a frame, red and white
    reflective tape along the sill, lamps, a plate and an underride guard below."""
    xo = x - 0.012
    mid, h = (z0 + z1) / 2, z1 - z0
    for y in (hw - 0.05, -(hw - 0.05)):  # the frame: corner posts, header and sill
        vv, f = box((0.03, 0.1, h), (xo, y, mid))
        mb.add(vv, f, "alloy")
    for z in (z1 - 0.06, z0 + 0.08):  # proud of the posts: coplanar faces rendered black in Cycles
        vv, f = box((0.03, 2 * hw, 0.12 if z < mid else 0.1), (xo - 0.008, 0, z))
        mb.add(vv, f, "alloy")
    vv, f = box((0.02, 0.025, h - 0.24), (xo - 0.012, 0, mid))  # the seam between the doors
    mb.add(vv, f, "plastic")
    for y in np.array([-0.72, -0.28, 0.28, 0.72]) * hw:  # locking bars with their handles
        mb.add(*cylinder(0.018, h - 0.3, 8, "z", (xo - 0.03, y, mid)), "chrome", smooth=True)
        vv, f = box((0.03, 0.05, 0.22), (xo - 0.04, y + 0.05, z0 + 0.55))
        mb.add(vv, f, "chrome")
    for y in (hw - 0.13, -(hw - 0.13)):  # hinges on the outer edges
        for z in np.linspace(z0 + 0.35, z1 - 0.35, 4):
            vv, f = box((0.03, 0.14, 0.06), (xo - 0.01, y, z))
            mb.add(vv, f, "alloy")
    n, w = 12, (2 * hw - 0.2) / 12  # conspicuity tape: alternating red and white
    for i in range(n):
        vv, f = box((0.01, w - 0.01, 0.05), (xo - 0.03, -hw + 0.1 + (i + 0.5) * w, z0 + 0.08))
        mb.add(vv, f, "tape_red" if i % 2 == 0 else "tape_white")
    for s in (1, -1):  # round tail lamps low on the box corners, and the guard's struts
        mb.add(*cylinder(0.09, 0.04, 16, "x", (xo - 0.01, s * (hw - 0.3), z0 + 0.28)), "lamp_tail")
        vv, f = box((0.08, 0.08, z0 - 0.45), (x + 0.25, s * (hw - 0.45), (z0 + 0.45) / 2 + 0.05))
        mb.add(vv, f, "plastic")
    _plate(mb, (0.02, 0.52, 0.12), (xo - 0.02, 0, z0 + 0.28))
    vv, f = box((0.12, 2 * hw * 0.92, 0.12), (x + 0.2, 0, 0.5))  # underride guard
    mb.add(vv, f, "plastic")
    flap = max(z0 - 0.25, 0.3)
    for s in (1, -1):  # mud flaps behind the rear wheels
        vv, f = box((0.01, 0.5, flap), (x + 0.6, s * (hw - 0.3), 0.25 + flap / 2))
        mb.add(vv, f, "rubber")


def bus(mb: MeshBuilder, v: dict, L: float, W: float, H: float):
    r = float(v.get("wheel_radius", 0.5))
    hw = W / 2 - 0.03  # the tyres stand proud of the body in their arches
    z0 = 0.3
    st = [(-L / 2, rounded_section(hw * 0.97, z0 + 0.05, H - 0.05, 0.25, top_half_w=hw * 0.9)),
          (-L / 2 + 0.15, rounded_section(hw, z0, H, 0.25, top_half_w=hw * 0.94)),
          (L / 2 - 0.15, rounded_section(hw, z0, H, 0.25, top_half_w=hw * 0.94)),
          (L / 2, rounded_section(hw * 0.97, z0 + 0.05, H - 0.08, 0.25, top_half_w=hw * 0.9))]
    vv, f = loft(st)
    mb.add(vv, f, "paint", smooth=True)
    zw0, zw1 = 0.36 * H, 0.86 * H
    # side window band, windscreen, rear window
    for s in (1, -1):
        vv, f = box((L - 1.6, 0.03, zw1 - zw0), (-0.3, s * (hw + 0.004), (zw0 + zw1) / 2))
        mb.add(vv, f, "glass")
    vv, f = box((0.04, W * 0.9, 0.86 * H - 0.3 * H), (L / 2 + 0.004, 0, 0.58 * H))
    mb.add(vv, f, "glass")
    # rear: a window in the upper third over a painted panel and the engine hatch's louvres (one
    # window over the whole back read as a flat toy panel on the real highway photos)
    vv, f = box((0.04, 2 * hw * 0.8, 0.2 * H), (-L / 2 - 0.004, 0, 0.76 * H))
    mb.add(vv, f, "glass")
    zl0, zl1 = z0 + 0.42, 0.44 * H
    for k in range(6):
        z = zl0 + (k + 0.5) * (zl1 - zl0) / 6
        vv, f = box((0.03, 2 * hw * 0.62, 0.35 * (zl1 - zl0) / 6), (-L / 2 - 0.006, 0, z))
        mb.add(vv, f, "plastic")
    vv, f = box((0.04, 2 * hw * 0.5, 0.16), (-L / 2 - 0.008, 0, 0.91 * H))  # rear route display
    mb.add(vv, f, "lamp_sign")
    _plate(mb, (0.02, 0.52, 0.12), (-L / 2 - 0.015, 0, z0 + 0.14))  # on the bumper
    # doors on the right (y < 0), full height glass panels
    doors = [L / 2 - 1.2, -0.2, -L / 2 + 2.2][: int(v.get("doors", 3))]
    for x in doors:
        vv, f = box((1.2, 0.04, 0.86 * H - z0 - 0.1), (x, -(hw + 0.008), (0.86 * H + z0 + 0.1) / 2))
        mb.add(vv, f, "glass")
    vv, f = box((0.04, W * 0.6, 0.2), (L / 2 + 0.01, 0, 0.93 * H))
    mb.add(vv, f, "lamp_sign")
    vv, f = box((L * 0.25, W * 0.6, 0.2), (-L * 0.1, 0, H + 0.05))  # roof air-conditioning unit
    mb.add(vv, f, "alloy")
    vv, f = box((L + 0.01, 2 * hw + 0.01, 0.28), (0, 0, z0 + 0.16))
    mb.add(vv, f, "plastic")
    for s in (1, -1):
        vv, f = box((0.05, 0.3, 0.15), (L / 2 + 0.01, s * (hw - 0.35), z0 + 0.45))
        mb.add(vv, f, "lamp_head")
        vv, f = box((0.05, 0.22, 0.5), (-L / 2 - 0.01, s * (hw - 0.2), z0 + 0.75))  # tall corner clusters
        mb.add(vv, f, "lamp_tail")
    for x in (L / 2 - 2.6, -L / 2 + 3.0):
        for s in (1, -1):
            _wheel(mb, x, s * (hw - 0.13), r, 0.3, "alloy", spokes=0)
            _arch(mb, x, s * (hw + 0.006), r, s, band=0.09)


# ====================================================================== people
def _ik(hip, foot, l1, l2, forward):
    """Knee (or elbow) of a two-bone chain from `hip` to `foot`, bending toward `forward`."""
    hip, foot = np.asarray(hip, float), np.asarray(foot, float)
    d = foot - hip
    dist = float(np.linalg.norm(d))
    dist = min(dist, l1 + l2 - 1e-4)
    u = d / max(np.linalg.norm(d), 1e-9)
    a = (l1 ** 2 - l2 ** 2 + dist ** 2) / (2 * dist)
    hgt = math.sqrt(max(l1 ** 2 - a ** 2, 0.0))
    fw = np.asarray(forward, float)
    fw = fw - u * (fw @ u)
    fw /= max(np.linalg.norm(fw), 1e-9)
    return hip + u * a + fw * hgt, hip + u * dist


def limb_lengths(J: dict) -> dict[str, float]:
    """Thigh, shin, upper arm and forearm lengths of the rest joints `J` (m)."""
    return {j: float(np.linalg.norm(J[b + ".L"] - J[a + ".L"]))
            for j, a, b in (("thigh", "hip", "knee"), ("shin", "knee", "ankle"),
                            ("upper", "shoulder", "elbow"), ("fore", "elbow", "wrist"))}


def walking_legs(J: dict, stride: float, h: float) -> tuple[np.ndarray, dict]:
    """Standing (stride 0) or mid-stride: each leg swung by `stride` (rad) about its hip, the
    pelvis lowered so the leading foot stays on the ground, the trailing leg pushing off with
    its heel raised and its knee bent (both legs straight read as a pair of compasses on the
    real photos). Returns the pelvis and the knee and ankle targets."""
    seg = limb_lengths(J)
    leg = seg["thigh"] + seg["shin"]
    pelvis = J["pelvis"] - [0, 0, (1 - math.cos(stride)) * leg]
    target = {}
    for s, ang in (("L", stride), ("R", -stride)):
        hip = pelvis + (J["hip." + s] - J["pelvis"])
        # the rest pose stands with the feet 0.4 m apart: bring them under the hips
        ankle = hip + rot_y(-ang) @ [0, -0.2 * (hip[1] - pelvis[1]), -leg]
        if ankle[0] < hip[0] - 1e-6:
            ankle = ankle + [0, 0, 0.035 * h]
        target["knee." + s], target["ankle." + s] = _ik(hip, ankle, seg["thigh"], seg["shin"], [1, 0, 0])
    return pelvis, target


def figure(mb: MeshBuilder, v: dict, joints: dict | None = None):
    """A person: MakeHuman's body in one of a few outfits (`assets_procedural.body`). Without
    `joints`: standing or walking on the ground (origin between the feet). With `joints`
    (riders): pelvis, lean, hands and feet given."""
    h = float(v.get("height_m", 1.72))
    J = body.rest_joints(v, h)
    seg = limb_lengths(J)
    arm = seg["upper"] + seg["fore"]
    stride = float(v.get("stride_rad", 0.0))
    if joints is None:
        pelvis, target = walking_legs(J, stride, h)
        lean, head_lift = (0.05 if stride else 0.0), 0.0
        hands = None
    else:
        target = {}
        pelvis, lean = np.asarray(joints["pelvis"], float), joints["lean"]
        for s, foot in zip("LR", joints["feet"]):
            hip = pelvis + (J["hip." + s] - J["pelvis"])
            # the ball of the foot on the peg or pedal: the ankle sits behind and above it
            ankle = np.asarray(foot, float) + [-0.06 * h, 0, 0.04 * h]
            target["knee." + s], target["ankle." + s] = _ik(hip, ankle, seg["thigh"], seg["shin"], [1, 0, 0.6])
        hands = [np.asarray(p, float) for p in joints["hands"]]
        # lean further when the grips are out of reach (the seats and bars were laid out
        # for longer arms than the body's)
        reach = 0.97 * arm + 0.045 * h
        while lean < 1.2 and max(np.linalg.norm(g - pelvis - rot_y(lean) @ (J["shoulder." + s] - J["pelvis"]))
                                 for g, s in zip(hands, "LR")) > reach:
            lean += 0.05
        head_lift = 0.6 * lean  # riders look ahead, not at the road under them
    target["pelvis"] = pelvis
    R = rot_y(lean)
    for k, (s, sign) in enumerate((("L", 1), ("R", -1))):
        sh = pelvis + R @ (J["shoulder." + s] - J["pelvis"])
        if hands is None:  # arms swing opposite to the legs, 9 deg off the body
            swing = -stride * 0.8 * sign
            wrist = sh + arm * 0.95 * np.array([math.sin(swing), sign * 0.15, -math.cos(swing)])
            bend = [-1, 0, 0]
        else:  # the palm on the grip: the wrist a hand's breadth short of it
            grip = hands[k]
            wrist = grip - 0.045 * h * (grip - sh) / np.linalg.norm(grip - sh)
            bend = [0, sign * 0.5, -1]
        target["elbow." + s], target["wrist." + s] = _ik(sh, wrist, seg["upper"], seg["fore"], bend)
    T = body.pose_transforms(J, target, lean, head_lift)
    slots = body.human()["regions"]  # skin, shirt, pants (a skirt too), shoes, hair
    if mb.bounds_only:
        mb.add(body.posed_bounds(v, h, T), [], "skin")
    else:
        for verts, faces, region in body.posed_meshes(v, h, T):
            mb.add(verts, faces, slots[region], smooth=True)
    if v.get("helmet"):
        Rh, a, b = T["head"]
        if v.get("helmet_kind") == "full_face":  # the whole head, chin to crown
            centre = (J["head"] + [0.01 * h, 0, 0.015 * h] - a) @ Rh.T + b
            for verts, faces, slot in _full_face_helmet(h):
                mb.add(xf(verts, Rh, centre), faces, slot, smooth=True)
        else:  # a cyclist's helmet or a motorcyclist's half helmet: a shell 2-3 cm round the skull
            skull = (J["head"] + [0.021 * h, 0, 0.057 * h] - a) @ Rh.T + b
            vv, f = ellipsoid((0.076 * h, 0.066 * h, 0.052 * h), skull, 16, 8)
            mb.add(xf(vv - skull, Rh, skull), f, "helmet", smooth=True)
    if v.get("bag") and joints is None:  # a backpack: rounded, its front inside the back
        hw, hz, r = 0.08 * h, 0.1 * h, 0.035 * h
        vv, f = loft([(x * h, rounded_section(hw * k, -hz * k, hz * k, r, n_corner=3))
                      for x, k in ((-0.05, 0.85), (-0.035, 1.0), (0.05, 1.0))])
        mb.add(xf(vv, R, pelvis + R @ np.array([-0.085 * h, 0, 0.2 * h])), f, "bag", smooth=True)


def _full_face_helmet(h: float):
    """A full-face motorcycle helmet round a head of a person `h` tall, about its centre (0.01 h
    before and 0.015 h above the head joint): a shell 0.17 h long, 0.144 h wide, from 0.09 h above
    the centre (3-4 cm over the crown) to 0.075 h below it (under the chin), widest at ear level,
    its lower half fuller than an ellipsoid's so that the opening round the neck stays ~0.8 of
    that width; a dark visor over the eyes across the front 130 deg."""
    ax, ay, az, a_low, cut = 0.085 * h, 0.072 * h, 0.09 * h, 0.12 * h, 0.075 * h

    def surf(th, ph, grow=1.0):
        z = (az if th >= 0 else a_low) * math.sin(th)
        return grow * np.array([ax * math.cos(th) * math.cos(ph), ay * math.cos(th) * math.sin(ph), z])

    ths = np.linspace(-math.asin(cut / a_low), math.pi / 2, 12)
    phs = np.linspace(-math.pi, math.pi, 25)
    yield (*grid(np.array([[surf(t, p) for p in phs] for t in ths])), "helmet")
    # the visor from the nose (0.025 h under the centre) to the brow (0.04 h over it)
    tv = np.linspace(-math.asin(0.025 * h / a_low), math.asin(0.04 * h / az), 5)
    pv = np.linspace(-math.radians(65), math.radians(65), 13)
    yield (*grid(np.array([[surf(t, p, 1.012) for p in pv] for t in tv])), "visor")


def person(mb: MeshBuilder, v: dict, L: float, W: float, H: float):
    mount = v.get("mount")
    if mount:  # the rider of a two-wheeler: posed on it, the two-wheeler itself left out
        BUILDERS[mount["cls"]](mb, {**mount["variant"], "part": "rider"}, *mount["variant"]["shape_dims"])
    else:
        figure(mb, {**v, "height_m": H})


# ====================================================================== two-wheelers
def _parts(mb: MeshBuilder, part: str) -> tuple[MeshBuilder, MeshBuilder]:
    """Where a two-wheeler builder puts (vehicle, rider) parts: `part` "all" builds both into
    `mb`; "vehicle" or "rider" builds only that one (the other goes to a scratch builder), so
    a ridden two-wheeler can be labelled as two instances, as COCO does."""
    scratch = MeshBuilder()
    return (mb if part in ("all", "vehicle") else scratch), (mb if part in ("all", "rider") else scratch)


def bicycle(mb: MeshBuilder, v: dict, L: float, W: float, H: float):
    veh, rid = _parts(mb, v.get("part", "all"))
    kind = v.get("kind", "city")
    r = float(v.get("wheel_radius", 0.35))
    wb = L - 2 * r
    xr, xf_ = -wb / 2, wb / 2
    tr = 0.028 if kind == "mountain" else 0.018
    for x in (xr, xf_):
        vv, f = torus(r - tr, tr, (x, 0, r), "y", 28, 6)
        veh.add(vv, f, "rubber", smooth=True)
        vv, f = torus(r - 2 * tr - 0.012, 0.012, (x, 0, r), "y", 28, 4)
        veh.add(vv, f, "alloy", smooth=True)
        # 32 steel spokes of 2.4 mm (a real wheel's 32-36 of 2 mm): 16 chrome ones of 8 mm
        # mirrored the sky into a light-grey disc on the real photos
        for k in range(16):
            a = k * math.pi / 16
            d = np.array([math.cos(a), 0, math.sin(a)]) * (r - 2 * tr - 0.015)
            vv, f = tube(np.array([x, 0, r]) - d, np.array([x, 0, r]) + d, 0.0012, 4)
            veh.add(vv, f, "spoke")
    bb = np.array([xr + 0.42 * wb, 0, r * 0.85])
    seat_top = np.array([xr + 0.27 * wb, 0, r + 0.56])
    head_top = np.array([xf_ - 0.16 * wb, 0, r + 0.5])
    head_bot = np.array([xf_ - 0.12 * wb, 0, r + 0.28])
    rad = 0.022 if kind != "road" else 0.017
    top_from = seat_top + (bb - seat_top) * (0.45 if kind == "city" else 0.08)
    for a, b in ((seat_top, bb), (bb, head_bot), (top_from, head_top), (head_top, head_bot),
                 (bb, [xr, 0, r]), (seat_top + (bb - seat_top) * 0.1, [xr, 0, r])):
        vv, f = tube(a, b, rad, 8)
        veh.add(vv, f, "paint", smooth=True)
    for s in (1, -1):
        vv, f = tube(head_bot, [xf_, s * 0.05, r], 0.013, 6)
        veh.add(vv, f, "paint")
    post = seat_top + np.array([-0.05, 0, 0.12])
    vv, f = tube(seat_top, post, 0.013, 6)
    veh.add(vv, f, "chrome")
    vv, f = ellipsoid((0.13, 0.075, 0.03), post + [0.0, 0, 0.02], 10, 5)
    veh.add(vv, f, "saddle", smooth=True)
    stem = head_top + np.array([0.04 if kind == "road" else -0.02, 0, 0.13 if kind == "city" else 0.06])
    vv, f = tube(head_top, stem, 0.015, 6)
    veh.add(vv, f, "chrome")
    bar_w = W / 2 - 0.01
    vv, f = tube(stem + [0, -bar_w, 0], stem + [0, bar_w, 0], 0.012, 6)
    veh.add(vv, f, "chrome")
    for s in (1, -1):
        vv, f = tube(stem + [0, s * (bar_w - 0.12), 0], stem + [0, s * bar_w, 0], 0.017, 6)
        veh.add(vv, f, "plastic")
    pedals = []
    for s, ang in ((1, 0.6), (-1, 0.6 + math.pi)):
        p = bb + np.array([0.17 * math.cos(ang), s * 0.12, 0.17 * math.sin(ang)])
        vv, f = tube(bb + [0, s * 0.06, 0], p, 0.01, 4)
        veh.add(vv, f, "alloy")
        vv, f = box((0.1, 0.08, 0.02), p)
        veh.add(vv, f, "plastic")
        pedals.append(p)
    vv, f = torus(0.09, 0.008, bb + [0, -0.05, 0], "y", 16, 4)
    veh.add(vv, f, "alloy")
    if kind == "city":
        vv, f = box((0.3, 0.03, 0.02), [xf_, 0, 2 * r + 0.03])
        veh.add(vv, f, "paint")
    if "rider" in v:
        rv = v["rider"]
        h = float(rv.get("height_m", 1.72))
        lean = {"road": 0.75, "mountain": 0.55, "city": 0.3}.get(kind, 0.45)
        pelvis = post + np.array([-0.02, 0, 0.06])
        hands = [stem + [0, bar_w - 0.06, 0], stem + [0, -(bar_w - 0.06), 0]]
        figure(rid, {**rv, "height_m": h}, {"pelvis": pelvis, "lean": lean, "hands": hands,
                                           "feet": [pedals[0] + [0, 0, 0.03], pedals[1] + [0, 0, 0.03]]})


def _silencer(mb, start, end, radius, material):
    """A silencer from `start` back to `end`, its open end dark (a closed rounded chrome end
    mirrored the sky: a white ball beside the rear wheel)."""
    vv, f = tube(start, end, radius, 10)
    mb.add(vv, f, material)
    vv, f = cylinder(radius - 0.01, 0.01, 10, "x", np.asarray(end, float) + [-0.002, 0, 0])
    mb.add(vv, f, "well")


def _arc_shell(mb, centre, radius, a0, a1, half_w, material, n=10, y0=0.0):
    """A mudguard: a strip of the cylinder (axis y) of `radius` about `centre` (x, z) from angle
    a0 to a1 (radians from +x toward +z), `half_w` either side of y0."""
    cx, cz = centre
    P = np.array([[[cx + radius * math.cos(t), y0 + s * half_w, cz + radius * math.sin(t)] for s in (-1, 1)]
                  for t in np.linspace(a0, a1, n)])
    vv, f = grid(P)
    mb.add(vv, f, material, smooth=True)


def _fork(mb, axle, top, half_gap, r_low, r_up, material):
    """Telescopic fork: two legs from the front axle (x, z) up to the steering head (x, z),
    thick sliders below, thinner stanchions above, a top clamp."""
    axle, top = np.asarray(axle, float), np.asarray(top, float)
    mid = axle + 0.45 * (top - axle)
    for s in (1, -1):
        a, m, t = ([p[0], s * half_gap, p[1]] for p in (axle, mid, top))
        mb.add(*tube(a, m, r_low, 8), "chrome" if material == "chrome" else "wheel", smooth=True)
        mb.add(*tube(m, t, r_up, 8), material, smooth=True)
    mb.add(*box((0.08, 2 * half_gap + 0.06, 0.04), [top[0], 0, top[1]]), "alloy")


def _road_bike(veh, kind, r, xr, xf_):
    """A sport bike (faired, an inline four, alloy twin spars) or a cruiser (a raked chrome
    fork, a teardrop tank, a V-twin, deep mudguards): what a motorcycle shows from the side and
    three quarters, where a box on two wheels read as a cart. Returns (seat_x, seat_z, bar,
    peg_x, peg_z) for the rider."""
    low = kind == "cruiser"
    rake = math.radians(32 if low else 24)
    fork_len = 0.8 if low else 0.66
    head = np.array([xf_ - fork_len * math.sin(rake), r + fork_len * math.cos(rake)])
    _fork(veh, (xf_, r), head, 0.1 if low else 0.09, 0.034, 0.026, "chrome" if low else "alloy")
    # mudguards: a cruiser's deep and painted, a sport bike's short
    if low:
        _arc_shell(veh, (xf_, r), r + 0.035, math.radians(15), math.radians(150), 0.075, "paint")
        _arc_shell(veh, (xr, r), r + 0.045, math.radians(25), math.radians(175), 0.12, "paint")
    else:
        _arc_shell(veh, (xf_, r), r + 0.03, math.radians(40), math.radians(125), 0.065, "paint")
    # engine: a dark crankcase low between the wheels, its cylinders up under the tank
    cx0, cx1 = xr + r + 0.12, xf_ - r - 0.1
    cmid = (cx0 + cx1) / 2
    veh.add(*loft([(cx0, rounded_section(0.13, r * 0.45, r + 0.12, 0.06)),
                   (cmid, rounded_section(0.16, r * 0.4, r + 0.2, 0.07)),
                   (cx1, rounded_section(0.14, r * 0.5, r + 0.16, 0.06))]), "engine", smooth=True)
    for s in (1, -1):  # round alloy covers on the crankcase's sides (clutch, alternator)
        veh.add(*cylinder(0.075, 0.02, 14, "y", (cmid + 0.05 * s, s * 0.165, r * 0.62)), "alloy")
    if low:  # a V-twin: two finned cylinders at +-30 deg, chrome heads, a round air cleaner
        base = np.array([cmid, 0, r + 0.12])
        for ang in (-0.55, 0.55):
            d = np.array([math.sin(ang), 0, math.cos(ang)])
            veh.add(*tube(base, base + 0.3 * d, 0.075, 12), "engine", smooth=True)
            for k in range(4):  # cooling fins
                veh.add(*tube(base + (0.08 + 0.05 * k) * d, base + (0.095 + 0.05 * k) * d, 0.09, 12), "alloy")
            veh.add(*tube(base + 0.3 * d, base + 0.36 * d, 0.07, 12), "chrome", smooth=True)
        veh.add(*cylinder(0.1, 0.04, 16, "y", (cmid, -0.19, r + 0.3)), "chrome")
    else:  # an inline four leaning forward, its headers sweeping down under it
        top_x = cx1 - 0.02
        veh.add(*loft([(cmid, rounded_section(0.17, r + 0.1, r + 0.3, 0.05)),
                       (top_x, rounded_section(0.15, r + 0.2, r + 0.42, 0.05))]), "engine", smooth=True)
        for y in (-0.09, -0.03, 0.03, 0.09):
            pts = [np.array([top_x + 0.04, y, r + 0.28]), np.array([cx1 + 0.06, y * 0.8, r * 0.5]),
                   np.array([cmid, y * 0.5, r * 0.28]), np.array([cx0 + 0.05, -0.05, r * 0.3])]
            for p0, p1 in zip(pts, pts[1:]):
                veh.add(*tube(p0, p1, 0.022, 6), "metal", smooth=True)
    # frame: a sport bike's alloy twin spars from the steering head to the swingarm pivot, a
    # cruiser's black backbone and down tube
    pivot = np.array([cx0 + 0.02, r + 0.12])
    if low:
        veh.add(*tube([head[0], 0, head[1] - 0.05], [cx0 + 0.1, 0, r + 0.35], 0.03, 8), "wheel")
        veh.add(*tube([head[0] + 0.02, 0, head[1] - 0.1], [cx1 + 0.05, 0, r * 0.4], 0.03, 8), "wheel")
    else:
        for s in (1, -1):
            veh.add(*tube([head[0], s * 0.1, head[1] - 0.04], [pivot[0], s * 0.15, pivot[1]], 0.035, 8), "alloy")
    for s in (1, -1):  # the swingarm
        veh.add(*tube([pivot[0], s * 0.13, pivot[1]], [xr, s * 0.13, r], 0.028, 8), "chrome" if low else "alloy")
    # the tank
    if low:
        veh.add(*ellipsoid((0.3, 0.15, 0.12), (head[0] - 0.32, 0, r + 0.5), 14, 8), "paint", smooth=True)
        veh.add(*cylinder(0.03, 0.02, 10, "z", (head[0] - 0.25, 0, r + 0.62)), "chrome")
        tank_rear = head[0] - 0.6
    else:
        tank_rear = head[0] - 0.55
        veh.add(*loft([(head[0] - 0.02, rounded_section(0.11, r + 0.5, r + 0.7, 0.06)),
                       (head[0] - 0.25, rounded_section(0.17, r + 0.42, r + 0.76, 0.09)),
                       (tank_rear, rounded_section(0.13, r + 0.44, r + 0.66, 0.07))]), "paint", smooth=True)
    # the seat and tail
    seat_x, seat_z = tank_rear - (0.18 if low else 0.05), r + (0.38 if low else 0.56)
    if low:
        veh.add(*loft([(tank_rear + 0.02, rounded_section(0.12, seat_z - 0.08, seat_z + 0.04, 0.05)),
                       (seat_x, rounded_section(0.19, seat_z - 0.1, seat_z + 0.02, 0.07)),
                       (xr + 0.15, rounded_section(0.13, seat_z - 0.06, seat_z + 0.06, 0.05))]), "saddle",
                smooth=True)
    else:
        veh.add(*loft([(tank_rear + 0.02, rounded_section(0.12, seat_z - 0.1, seat_z, 0.05)),
                       (seat_x - 0.12, rounded_section(0.14, seat_z - 0.1, seat_z + 0.01, 0.05)),
                       (xr + 0.2, rounded_section(0.1, seat_z - 0.05, seat_z + 0.09, 0.04))]), "saddle",
                smooth=True)
        # the tail cowl rising over the rear wheel, the side panels under the seat
        veh.add(*loft([(seat_x + 0.05, rounded_section(0.14, r + 0.3, seat_z - 0.06, 0.06)),
                       (xr + 0.25, rounded_section(0.12, r + 0.38, seat_z + 0.02, 0.05)),
                       (xr - r + 0.1, rounded_section(0.06, r + 0.42, r + 0.52, 0.03))]), "paint", smooth=True)
        # the fairing: a nose round the headlight, its sides down past the engine's top, a screen
        veh.add(*loft([(xf_ - 0.12, rounded_section(0.08, r + 0.4, r + 0.56, 0.05)),
                       (head[0] + 0.05, rounded_section(0.19, r + 0.12, r + 0.68, 0.1)),
                       (head[0] - 0.2, rounded_section(0.2, r * 0.55, r + 0.5, 0.1, top_half_w=0.17))]),
                "paint", smooth=True)
        g0 = np.array([head[0] + 0.02, 0, r + 0.74])
        vv, f = box((0.03, 0.2, 0.16))
        veh.add(xf(vv, rot_y(-0.55), g0), f, "glass")
    # grips ~0.6 m ahead of the hips: a sport bike's clip-ons just behind the steering head, a
    # cruiser's bar pulled back to the rider (0.84 m ahead he held it at arm's length)
    bar = np.array([head[0] - (0.18 if low else 0.02), 0, r + (0.66 if low else 0.65)])
    peg_x, peg_z = seat_x + (0.35 if low else 0.05), r * (0.7 if low else 0.95)
    # the silencer: chrome on a cruiser (a long pipe along the right), brushed steel otherwise
    if low:
        _silencer(veh, [cx1, -0.17, r * 0.55], [xr - 0.25, -0.2, r * 0.75], 0.045, "chrome")
    else:
        _silencer(veh, [xr + 0.35, -0.16, r * 0.8], [xr - 0.08, -0.18, r + 0.15], 0.05, "metal")
    # the headlight: a cruiser's in a chrome bucket on the fork, a sport bike's in its nose
    lx, lz = (xf_ - 0.3, r + 0.55) if low else (xf_ - 0.1, r + 0.48)
    veh.add(*cylinder(0.1 if low else 0.065, 0.1, 14, "x", (lx - 0.02, 0, lz)), "chrome" if low else "paint")
    veh.add(*cylinder(0.085 if low else 0.055, 0.02, 14, "x", (lx + 0.04, 0, lz)), "lamp_head")
    return seat_x, seat_z, bar, peg_x, peg_z


def _scooter(veh, v, r, xr, xf_):
    """A step-through scooter: a leg shield and nose round the steering column, a low floor,
    the body cowl under a long seat half over the rear wheel, the engine and belt case on the
    left of the rear wheel. Returns (seat_x, seat_z, bar, peg_x, peg_z) for the rider."""
    floor_z = r * 0.85
    veh.add(*box((xf_ - xr - 0.85, 0.32, 0.06), ((xf_ - 0.36 + xr + 0.55) / 2, 0, floor_z + 0.03)), "plastic")
    # the leg shield: a shell leaning back 18 deg from over the front mudguard to the bar,
    # rounded in front, widest at the rider's knees (a slab with a flat top read as a fridge)
    lean = math.tan(math.radians(18))
    z0, z1 = r + 0.1, r + 0.74
    stations = []
    for z in np.linspace(z0, z1, 7):
        t = (z - z0) / (z1 - z0)
        front = xf_ - 0.2 - lean * (z - z0)
        hw = 0.13 + 0.08 * math.sin(math.pi * min(1.0, 0.2 + t))  # widest a little above the middle
        depth = 0.16 - 0.06 * t
        # the section in (y, x): a rounded front (a half ellipse) and a flat back face
        sec = [(hw * math.cos(a), front - depth + depth * math.sin(a)) for a in np.linspace(0, math.pi, 9)]
        stations.append((z, sec))
    vv, f = loft(stations)
    veh.add(vv[:, [2, 1, 0]], [q[::-1] for q in f], "paint", smooth=True)  # stations along z
    veh.add(*loft([(xf_ - 0.42, rounded_section(0.16, floor_z, r + 0.16, 0.05)),
                   (xf_ - 0.2, rounded_section(0.12, r * 0.95, r + 0.16, 0.05))]), "paint", smooth=True)
    _arc_shell(veh, (xf_, r), r + 0.03, math.radians(25), math.radians(125), 0.07, "paint")
    for s in (1, -1):  # the short fork under the front mudguard
        veh.add(*tube([xf_, s * 0.07, r], [xf_ - 0.1, s * 0.07, r + 0.28], 0.022, 6), "wheel")
    # the body cowl under the seat: rounded, widest over the engine, over the top of the wheel
    veh.add(*loft([(xr + 0.6, rounded_section(0.16, floor_z, r + 0.48, 0.08)),
                   (xr + 0.32, rounded_section(0.21, r + 0.02, r + 0.52, 0.13)),
                   (xr - 0.02, rounded_section(0.18, r + 0.2, r + 0.5, 0.12)),
                   (xr - 0.2, rounded_section(0.1, r + 0.3, r + 0.46, 0.06))]), "paint", smooth=True)
    seat_x, seat_z = xr + 0.4, r + 0.55
    veh.add(*loft([(xr + 0.68, rounded_section(0.13, r + 0.47, seat_z + 0.02, 0.05)),
                   (xr + 0.3, rounded_section(0.16, r + 0.48, seat_z + 0.05, 0.06)),
                   (xr - 0.08, rounded_section(0.12, r + 0.46, seat_z + 0.04, 0.05))]), "saddle", smooth=True)
    # a step-through scooter: seat 0.79 m, grips ~1.04 m high and ~0.6 m ahead of the hips
    # (at 1.19 m and 0.84 m ahead the rider reached up and out, and read as waving)
    bar = np.array([xf_ - 0.25, 0, r + 0.8])
    veh.add(*loft([(bar[0] - 0.08, rounded_section(0.12, bar[2] - 0.05, bar[2] + 0.06, 0.04)),
                   (bar[0] + 0.1, rounded_section(0.09, bar[2] - 0.06, bar[2] + 0.03, 0.04))]), "paint",
            smooth=True)
    # what a scooter shows from behind besides its smooth body: the engine and belt case on
    # the left of the rear wheel, the silencer on the right, a grab rail behind the seat and,
    # on every other one, a top box on its rack with a red reflector
    veh.add(*box((0.5, 0.09, 0.2), (xr + 0.2, 0.15, r * 0.95)), "metal")
    _silencer(veh, [xr + 0.25, -0.14, r * 0.6], [xr - 0.12, -0.17, r * 0.85], 0.04, "metal")
    rail = [(xr + 0.3, 0.14, r + 0.5), (xr - 0.08, 0.14, r + 0.52), (xr - 0.08, -0.14, r + 0.52),
            (xr + 0.3, -0.14, r + 0.5)]
    for a, b in zip(rail, rail[1:]):
        veh.add(*tube(a, b, 0.012, 6), "plastic")
    if int(v.get("seed", 0)) % 2 == 0:
        z0 = r + 0.56
        veh.add(*loft([(x, rounded_section(0.2 * k, z0, z0 + 0.3 * k, 0.07)) for x, k in
                       ((xr - 0.22, 0.9), (xr - 0.19, 1.0), (xr + 0.1, 1.0), (xr + 0.14, 0.9))]), "plastic",
                smooth=True)
        veh.add(*box((0.01, 0.22, 0.045), (xr - 0.222, 0, z0 + 0.13)), "tape_red")
    return seat_x, seat_z, bar, 0.0, floor_z + 0.06


def motorcycle(mb: MeshBuilder, v: dict, L: float, W: float, H: float):
    veh, rid = _parts(mb, v.get("part", "all"))
    kind = v.get("kind", "sport")
    r = float(v.get("wheel_radius", 0.31))
    tr = 0.06 if kind != "scooter" else 0.05
    wb = L - 2 * r - 0.1
    xr, xf_ = -wb / 2 - 0.05, wb / 2 - 0.05
    # the rear tyre is the wide one (a sport bike's 180 mm; the front's 120 mm); the wheels are
    # a rim on five spokes around the hub and a brake disc, not solid discs (solid light discs
    # read as a toy on real photos), black but for a cruiser's chrome
    spokes = "chrome" if kind == "cruiser" else "wheel"
    for x, t in ((xr, tr * (1.2 if kind == "scooter" else 1.45)), (xf_, tr)):
        vv, f = torus(r - t, t, (x, 0, r), "y", 24, 8)
        veh.add(vv, f, "rubber", smooth=True)
        vv, f = torus(r - 2 * t, 0.018, (x, 0, r), "y", 24, 6)
        veh.add(vv, f, spokes, smooth=True)
        vv, f = cylinder(0.06, 2 * t, 12, "y", (x, 0, r))
        veh.add(vv, f, spokes)
        vv, f = cylinder(0.4 * r, 0.008, 16, "y", (x, -0.05, r))
        veh.add(vv, f, "alloy")
        spoke, f = box((r - 2 * t - 0.06, 0.03, 0.028), (0, 0, 0))
        for k in range(5):
            a = 2 * np.pi * k / 5 + 0.3
            c = np.array([x, 0, r]) + (r - 2 * t + 0.06) / 2 * np.array([np.cos(a), 0, np.sin(a)])
            veh.add(xf(spoke, rot_y(-a), c), f, spokes)
    if kind == "scooter":
        seat_x, seat_z, bar, peg_x, peg_z = _scooter(veh, v, r, xr, xf_)
    else:
        seat_x, seat_z, bar, peg_x, peg_z = _road_bike(veh, kind, r, xr, xf_)
    if kind != "scooter":
        for s in (1, -1):  # risers from the top clamp to the bar
            vv, f = tube(bar + [0.1, s * 0.09, -0.1], bar + [0.0, s * 0.09, -0.01], 0.018, 6)
            veh.add(vv, f, "chrome" if kind == "cruiser" else "alloy")
    # grips ~0.6 m apart on sport bikes and scooters, ~0.7 m on a cruiser (the box's width
    # is the mirrors'): at the box's 0.9 m a rider seen from behind-left held one arm out
    # sideways
    bar_w = min(W / 2 - 0.02, 0.41 if kind == "cruiser" else 0.36)
    vv, f = tube(bar + [0, -bar_w, 0], bar + [0, bar_w, 0], 0.014, 6)
    veh.add(vv, f, "chrome")
    if kind == "scooter":  # the headlight in the bar's cover; a road bike's is in its nose or bucket
        vv, f = cylinder(0.06, 0.04, 12, "x", bar + [0.12, 0, -0.02])
        veh.add(vv, f, "lamp_head")
    vv, f = box((0.04, 0.14, 0.06), (xr - r + 0.05, 0, r + 0.42))
    veh.add(vv, f, "lamp_tail")
    # what every road-legal two-wheeler shows from behind: a hugger over the rear tyre, the
    # number plate on its hanger under the tail lamp, amber indicators on stalks either side
    tail_x = xr - r + 0.07
    vv, f = box((0.3, 0.12, 0.012), (0, 0, 0))
    veh.add(xf(vv, rot_y(0.2), [xr - r + 0.2, 0, r + 0.36]), f, "wheel")
    _plate(veh, (0.012, 0.2, 0.13), (tail_x, 0, r + 0.28), R=rot_y(-0.25), chars=4)
    for s in (1, -1):
        vv, f = tube([tail_x + 0.06, s * 0.05, r + 0.38], [tail_x + 0.04, s * 0.15, r + 0.38], 0.008, 6)
        veh.add(vv, f, "wheel")
        vv, f = box((0.05, 0.035, 0.035), (tail_x + 0.04, s * 0.165, r + 0.38))
        veh.add(vv, f, "indicator")
    if "rider" in v:
        rv = v["rider"]
        lean = {"sport": 0.75, "cruiser": 0.05, "scooter": 0.1}.get(kind, 0.4)
        pelvis = np.array([seat_x, 0, seat_z + 0.06])
        hands = [bar + [0, bar_w - 0.06, 0], bar + [0, -(bar_w - 0.06), 0]]
        feet = [np.array([peg_x, s * 0.2, peg_z]) for s in (1, -1)]
        figure(rid, rv, {"pelvis": pelvis, "lean": lean, "hands": hands, "feet": feet})


# ====================================================================== traffic light
LAMP_COLORS = {"red": (1.0, 0.05, 0.02), "amber": (1.0, 0.45, 0.0), "green": (0.05, 1.0, 0.35)}


def traffic_light(mb: MeshBuilder, v: dict, L: float, W: float, H: float, state: str | None = "red"):
    """The signal head facing +x; the lamp of `state` is lit (emission), the others dark."""
    back = v.get("kind") == "backplate"
    hw = (W - (0.18 if back else 0.0)) / 2
    hh = H - (0.14 if back else 0.0)
    depth = 0.24
    x0 = -L / 2
    vv, f = loft([(x0, rounded_section(hw, (H - hh) / 2, (H + hh) / 2, 0.04)),
                  (x0 + depth, rounded_section(hw, (H - hh) / 2, (H + hh) / 2, 0.04))])
    mb.add(vv, f, "housing", smooth=True)
    if back:
        vv, f = box((0.02, W, H), (x0 + 0.01, 0, H / 2))
        mb.add(vv, f, "housing")
    lr = min(hw * 0.78, hh / 6 * 0.8)
    for k, name in enumerate(("red", "amber", "green")):
        zc = (H - hh) / 2 + hh * (5 - 2 * k) / 6
        slot = f"lamp_{name}" if state == name else f"lamp_{name}_off"
        vv, f = cylinder(lr, 0.03, 20, "x", (x0 + depth + 0.01, 0, zc))
        mb.add(vv, f, slot, smooth=False)
        # visor: a hood over the lamp reaching the front of the box
        vd = L - depth
        vv, f = box((vd, 2 * lr + 0.04, 0.015), (x0 + depth + vd / 2, 0, zc + lr + 0.02))
        mb.add(vv, f, "housing")
        for s in (1, -1):
            vv, f = box((vd * 0.8, 0.012, lr * 1.2), (x0 + depth + vd * 0.4, s * (lr + 0.02), zc + lr * 0.4))
            mb.add(vv, f, "housing")


def traffic_light_pole(v: dict, L: float, H: float) -> MeshBuilder:
    """The pole under the head (scenery: not part of the labelled object)."""
    mb = MeshBuilder()
    mount = float(v.get("mount_height_m", 2.6))
    vv, f = cylinder(0.06, mount + H * 0.6, 12, "z", (-L / 2 - 0.07, 0, (-mount + H * 0.6) / 2))
    mb.add(vv, f, "pole", smooth=True)
    vv, f = box((0.1, 0.08, 0.08), (-L / 2 - 0.03, 0, H * 0.5))
    mb.add(vv, f, "pole")
    return mb


BUILDERS = {"car": car, "truck": truck, "bus": bus, "person": person, "bicycle": bicycle,
            "motorcycle": motorcycle, "traffic light": traffic_light}


def build_shape(cls: str, variant: dict, dims, state: str | None = None) -> MeshBuilder:
    """Geometry of one object, fitted exactly to `dims`."""
    L, W, H = (float(x) for x in variant.get("shape_dims", dims))
    mb = MeshBuilder()
    if cls == "traffic light":
        traffic_light(mb, variant, L, W, H, state or "red")
    else:
        BUILDERS[cls](mb, variant, L, W, H)
        if cls in ("bicycle", "motorcycle") and "rider" not in variant:
            on_side_stand(mb, float(variant.get("wheel_radius", 0.33)))
    fit_to_dims(mb, dims)
    return mb


PARKED_LEAN_DEG = 5.0  # how far a side stand holds a parked two-wheeler off vertical


def on_side_stand(mb: MeshBuilder, r: float) -> None:
    """A parked two-wheeler leans onto a side stand on its left (+y): an upright riderless
    bicycle or motorcycle read as odd in real photos (the Udacity freeway shoulder). The
    lean turns it about the line where its tyres meet the ground; `fit_to_dims` then
    squeezes it back into its box (about 10 % narrower), so placement and labels keep the
    catalog's box."""
    lean = math.radians(PARKED_LEAN_DEG)
    mb.verts = [xf(p, rot_x(-lean)) for p in mb.verts]
    lo, hi = mb.vertices.min(0), mb.vertices.max(0)
    x = lo[0] + 0.42 * (hi[0] - lo[0])  # just behind the middle, where the frame is low
    top = xf([[x, 0.04, 0.8 * r]], rot_x(-lean))[0]
    mb.add(*tube(top, [x - 0.12, top[1] + 0.15, 0.0], 0.012, 6), "chrome")  # the stand


def part_box(cls: str, variant: dict, part: str = "all") -> tuple[np.ndarray, np.ndarray]:
    """(min, max) corners of the unfitted geometry of a variant (a two-wheeler's `part`:
    "all", "vehicle", "rider") in the builder's frame. Cached: the planner asks for a ridden
    two-wheeler's parts in every frame of its track, and each is a whole build."""
    lo, hi = _part_box(cls, json.dumps(variant, sort_keys=True), part)
    return np.array(lo), np.array(hi)


@functools.lru_cache(maxsize=4096)
def _part_box(cls: str, variant_json: str, part: str) -> tuple[tuple, tuple]:
    variant = json.loads(variant_json)
    mb = MeshBuilder(bounds_only=True)
    BUILDERS[cls](mb, {**variant, "part": part}, *variant["shape_dims"])
    v = mb.vertices
    return tuple(v.min(0)), tuple(v.max(0))


def natural_extent(mb: MeshBuilder) -> np.ndarray:
    v = mb.vertices
    return v.max(0) - v.min(0)


def fit_to_dims(mb: MeshBuilder, dims) -> np.ndarray:
    """Scale and shift all parts so their tight box is `dims`, centred, bottom at z=0.
    Returns the scale applied per axis (close to 1 when the builder matched the catalog)."""
    v = mb.vertices
    lo, hi = v.min(0), v.max(0)
    scale = np.asarray(dims, float) / np.maximum(hi - lo, 1e-9)
    centre = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])
    mb.verts = [(p - centre) * scale for p in mb.verts]
    return scale
