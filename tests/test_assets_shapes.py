"""Vehicle shapes without Blender (assets_procedural/shapes.py on a MeshBuilder)."""

import json

import cv2
import numpy as np

from assets_procedural.meshkit import MeshBuilder
from assets_procedural.shapes import BUILDERS, CAR_SHAPES
from blendgen.scene.catalog import sample_variant
from test_assets_body import _regions


def test_bus_rear_is_a_window_over_a_panel_and_louvres():
    """Seen from behind (most dashcam views of a bus), one window over the whole back read as a
    flat toy panel on the real highway photos: the rear window keeps to the upper third, the
    engine hatch's louvres sit below it, tall lamp clusters at the corners."""
    rng = np.random.default_rng(2)
    for _ in range(4):
        v, (L, W, H) = sample_variant("bus", rng)
        mb = MeshBuilder()
        BUILDERS["bus"](mb, v, L, W, H)
        rear = -L / 2 + 0.05
        parts = _regions(mb)
        glass = parts["glass"]
        back = glass[glass[:, 0] < rear]
        assert len(back) and back[:, 2].min() > 0.6 * H and back[:, 2].max() < 0.9 * H
        plastic = parts["plastic"]
        louvres = plastic[(plastic[:, 0] < rear) & (plastic[:, 2] > 0.6) & (plastic[:, 2] < 0.5 * H)]
        assert len(np.unique(np.round(louvres[:, 2], 3))) >= 12  # six slats, top and bottom faces
        lamps = parts["lamp_tail"]
        assert np.ptp(lamps[lamps[:, 0] < rear][:, 2]) >= 0.45


def _silhouette_from_behind(mb, slot, cm=0.01):
    """Occupancy of the (y, z) plane, in `cm` cells, by the faces of `slot` seen along x."""
    v, mat = mb.vertices, np.asarray(mb.mat)
    img = np.zeros((400, 400), np.uint8)  # y in [-2, 2) m, z in [0, 4) m
    for i in np.flatnonzero(mat == mb.slots.index(slot)):
        yz = v[mb.faces[i]][:, 1:]
        cv2.fillPoly(img, [np.round((yz + [2.0, 0.0]) / cm).astype(np.int32)], 1)
    return img


def test_car_bumpers_stand_clear_of_the_road_over_the_tyres():
    """A body down to the sills end to end stood on the road seen from behind; a real car shows a
    dark gap under its rear bumper with a tyre either side. Behind the rear tyres nothing is
    lower than 0.14 of the car's height; the tyres reach the road."""
    rng = np.random.default_rng(3)
    kinds = set()
    while kinds != set(CAR_SHAPES):
        v, (L, W, H) = sample_variant("car", rng)
        kinds.add(v["kind"])
        mb = MeshBuilder()
        BUILDERS["car"](mb, v, L, W, H)
        parts = _regions(mb)
        p = CAR_SHAPES[v["kind"]]
        behind = -p["axle"] * L - v.get("wheel_radius", 0.33) - 0.25
        rest = np.vstack([x for slot, x in parts.items() if slot not in ("rubber", "alloy", "chrome", "well")])
        assert rest[rest[:, 0] < behind][:, 2].min() > 0.14 * H, v["kind"]
        assert parts["rubber"][:, 2].min() < 0.01


def test_car_tail_has_no_light_strip_between_the_lamps():
    """A chrome garnish strip between the tail lamps mirrored the sky and read as a second plate:
    between the lamps only a small badge is bright metal."""
    rng = np.random.default_rng(11)
    for _ in range(6):
        v, (L, W, H) = sample_variant("car", rng)
        mb = MeshBuilder()
        BUILDERS["car"](mb, {**v, "chrome_trim": True}, L, W, H)
        chrome = _regions(mb)["chrome"]
        tail = chrome[(chrome[:, 0] < -L / 2 + 0.05) & (chrome[:, 2] > 0.4 * H)]
        assert len(tail) and np.ptp(tail[:, 1]) < 0.15


def test_car_rear_window_is_framed_and_tail_lamps_hug_the_tail():
    """Seen from behind, a car's rear was one dark panel from the belt to the roof (YOLOX-Nano
    took hatchbacks, SUVs and vans for buses on the real highway photos) with red boxes standing
    out of the rounded tail like ears. The rear window is an inset panel within a painted
    tailgate, and every tail-lamp point lies on the body's outline seen from behind."""
    rng = np.random.default_rng(3)
    kinds = set()
    for _ in range(16):
        v, (L, W, H) = sample_variant("car", rng)
        kinds.add(v["kind"])
        mb = MeshBuilder()
        BUILDERS["car"](mb, v, L, W, H)
        parts = _regions(mb)
        glass, paint = parts["glass"], parts["paint"]
        roof_rear = paint[paint[:, 2] > H - 0.01][:, 0].min()
        back = glass[glass[:, 0] < roof_rear + 0.02]  # behind the side windows: the rear window only
        assert len(back) == 4
        assert np.ptp(back[:, 1]) < 0.8 * np.ptp(paint[:, 1])
        belt = CAR_SHAPES[v["kind"]]["belt"] * H
        assert back[:, 2].min() > belt + 0.04 and back[:, 2].max() < H - 0.05
        body = cv2.dilate(_silhouette_from_behind(mb, "paint"), np.ones((3, 3), np.uint8))
        lamps = parts["lamp_tail"]
        cells = np.round((lamps[:, 1:] + [2.0, 0.0]) / 0.01).astype(int)
        assert body[cells[:, 1], cells[:, 0]].all()
    assert kinds == set(CAR_SHAPES)


def test_motorcycle_plates_carry_characters_on_their_outer_face():
    """A plain white plate glowed like a sticker on the real photos: a motorcycle's plate carries
    dark characters, on its outer face and inside its outline."""
    rng = np.random.default_rng(4)
    for _ in range(3):
        v, (L, W, H) = sample_variant("motorcycle", rng)
        mb = MeshBuilder()
        BUILDERS["motorcycle"](mb, {**v, "part": "vehicle"}, L, W, H)
        parts = _regions(mb)
        plate, glyphs = parts["plate"], parts["plate_text"]
        assert len(glyphs) >= 4 * 2 * 8  # four characters of two segments or more
        assert plate[:, 1].min() < glyphs[:, 1].min() and glyphs[:, 1].max() < plate[:, 1].max()
        assert plate[:, 2].min() < glyphs[:, 2].min() and glyphs[:, 2].max() < plate[:, 2].max()
        # on the outer face: beyond the plate along its thinnest axis (the plate is tilted)
        c = plate.mean(0)
        n = np.linalg.svd(plate - c)[2][-1]
        n = n if n[0] < 0 else -n
        assert ((glyphs - c) @ n).min() >= ((plate - c) @ n).max() - 1e-6


def test_riders_wear_the_helmet_of_their_two_wheeler():
    """A 2-3 cm shell over the skull read as a bare head on sport riders (skin at the ears and
    nape): a sport rider's full-face helmet holds the whole head above the neck with a visor in
    front; a scooter or cruiser rider's half helmet and a cyclist's stay a shell over the skull."""
    from scipy.spatial import Delaunay

    rng = np.random.default_rng(6)

    def rider(cls, kind=None):
        while True:
            v, (L, W, H) = sample_variant(cls, rng)
            if v.get("rider", {}).get("helmet") and kind in (None, v["kind"]):
                mb = MeshBuilder()
                BUILDERS[cls](mb, {**v, "part": "rider"}, L, W, H)
                return _regions(mb)

    for _ in range(2):
        parts = rider("motorcycle", "sport")
        helmet, skin = parts["helmet"], parts["skin"]
        assert np.ptp(helmet[:, 1]) > 0.23 and np.ptp(helmet[:, 2]) > 0.25
        # 8 cm over its lowest point: ears, eyes and crown (the neck enters from below, behind
        # when a sport rider leans)
        head = skin[skin[:, 2] > helmet[:, 2].min() + 0.08]
        assert len(head) > 100
        assert Delaunay(helmet).find_simplex(head).min() >= 0, "skin of the head outside the helmet"
        assert parts["visor"][:, 0].mean() > helmet[:, 0].mean() + 0.05  # in front: the bike faces +x
    for cls, kind in (("motorcycle", "scooter"), ("motorcycle", "cruiser"), ("bicycle", None)):
        parts = rider(cls, kind)
        assert "visor" not in parts and np.ptp(parts["helmet"][:, 2]) < 0.2


def test_scooters_show_engine_case_silencer_rail_and_top_box_from_behind():
    """A scooter's back was a smooth coloured blob (YOLOX-Nano found 16 of 85): the belt case
    left of the rear wheel, the silencer right of it, a grab rail behind the seat and, on every
    other scooter, a top box with a red reflector."""
    rng = np.random.default_rng(8)
    boxes = set()
    while boxes != {True, False}:
        v, (L, W, H) = sample_variant("motorcycle", rng)
        if v["kind"] != "scooter":
            continue
        mb = MeshBuilder()
        BUILDERS["motorcycle"](mb, {**v, "part": "vehicle"}, L, W, H)
        parts = _regions(mb)
        metal = parts["metal"]
        assert metal[:, 1].max() > 0.15 and metal[:, 1].min() < -0.15  # case on the left, silencer right
        top_box = "tape_red" in parts
        assert top_box == (v["seed"] % 2 == 0)
        if top_box:  # the reflector on the box's back, the box over the seat's height
            assert parts["tape_red"][:, 0].min() < parts["rubber"][:, 0].min() + 0.3
            assert parts["plastic"][:, 2].max() > 0.6 * H
        boxes.add(top_box)


def test_motorcycle_shows_a_plate_indicators_and_open_wheels():
    """Seen from behind, the motorcycles of the real-photo runs were a narrow tyre under a red
    block with a white ball beside it (the silencer's chrome end mirroring the sky), and from
    the side their wheels were solid light discs. A road-legal bike shows a plate under the
    tail lamp, indicators either side, a wide rear tyre and a dark silencer opening; its
    wheels are a rim on spokes."""
    rng = np.random.default_rng(5)
    kinds = set()
    for _ in range(12):
        v, (L, W, H) = sample_variant("motorcycle", rng)
        kinds.add(v.get("kind", "sport"))
        mb = MeshBuilder()
        BUILDERS["motorcycle"](mb, {**v, "part": "vehicle"}, L, W, H)
        parts = _regions(mb)
        tyres = parts["rubber"]
        rear_x = tyres[:, 0].min()
        plate = parts["plate"]
        # at the back, above the rear tyre and below the tail lamp, about 0.2 m wide
        assert plate[:, 0].max() < rear_x + 0.15
        assert plate[:, 2].min() > tyres[tyres[:, 0] < rear_x + 0.1][:, 2].max() - 0.05
        assert plate[:, 2].max() < parts["lamp_tail"][:, 2].min()
        assert 0.15 < np.ptp(plate[:, 1]) < 0.3
        signs = parts["indicator"]
        assert signs[:, 1].min() < -0.12 and signs[:, 1].max() > 0.12
        mid_x = tyres[:, 0].mean()
        rear, front = tyres[tyres[:, 0] < mid_x], tyres[tyres[:, 0] > mid_x]
        assert np.ptp(rear[:, 1]) > 1.15 * np.ptp(front[:, 1])
        # no solid disc inside the tyres: no face in a wheel's plane about its axle spans the
        # wheel's radius
        r = np.ptp(rear[:, 2]) / 2
        axles = np.array([[rear[:, 0].mean(), r], [front[:, 0].mean(), r]])
        for face, k in zip(mb.faces, mb.mat):
            f = mb.vertices[face]
            near = np.linalg.norm(axles - f[:, [0, 2]].mean(0), axis=1).min() < 0.5 * r
            if mb.slots[k] != "rubber" and near and np.ptp(f[:, 1]) < 0.02:
                assert min(np.ptp(f[:, 0]), np.ptp(f[:, 2])) < r, mb.slots[k]
    assert len(kinds) >= 2


def test_bicycle_wheels_have_fine_steel_spokes():
    """A wheel's 32-36 spokes are 2 mm steel wires: sixteen 8 mm chrome ones mirrored the sky
    into a light-grey disc on the real photos."""
    rng = np.random.default_rng(7)
    for _ in range(4):
        v, (L, W, H) = sample_variant("bicycle", rng)
        mb = MeshBuilder()
        BUILDERS["bicycle"](mb, {**v, "part": "vehicle"}, L, W, H)
        spokes = _regions(mb)["spoke"]
        # each spoke is a 4-sided tube: its section is the spread across the wheel's plane
        assert np.ptp(spokes[:, 1]) < 0.004
        per_wheel = np.sum(np.asarray(mb.mat) == mb.slots.index("spoke")) / 2
        assert per_wheel >= 16 * 6  # 16 wheel-wide tubes (32 spokes) of 4 sides and 2 caps


def test_car_wheels_show_dark_gaps_between_alloy_spokes():
    """From the side a car's rim was one light disc (a hubcap): now five spokes with the dark
    brake and well between them, and a truck's or bus's steel disc stays whole."""
    rng = np.random.default_rng(4)
    for cls, spoked in (("car", True), ("car", True), ("truck", False)):
        v, (L, W, H) = sample_variant(cls, rng)
        mb = MeshBuilder()
        BUILDERS[cls](mb, v, L, W, H)
        parts = _regions(mb)
        tyre = parts["rubber"]
        tyre = tyre[(tyre[:, 1] > 0) & (tyre[:, 0] > 0) & (tyre[:, 2] < 1.3)]  # the front left wheel
        x0, r = (tyre[:, 0].min() + tyre[:, 0].max()) / 2, tyre[:, 2].max() / 2
        rim = "chrome" if v.get("chrome_trim") else "alloy"
        img = np.zeros((300, 600), np.uint8)  # x in [x0 - 1.5, x0 + 1.5), z in [0, 1.5) m, 5 mm cells
        mat = np.asarray(mb.mat)
        outer = tyre[:, 1].max() - 0.03  # faces on the wheel's outer face
        for i in np.flatnonzero(mat == mb.slots.index(rim)):
            p = mb.vertices[mb.faces[i]]
            if p[:, 1].min() > outer:
                cv2.fillPoly(img, [np.round((p[:, [0, 2]] - [x0 - 1.5, 0.0]) / 0.005).astype(np.int32)], 1)
        a = np.linspace(0, 2 * np.pi, 180, endpoint=False)
        ring = img[np.round(r * (1 + 0.45 * np.sin(a)) / 0.005).astype(int),
                   np.round((1.5 + 0.45 * r * np.cos(a)) / 0.005).astype(int)]
        if spoked:
            assert 0.2 < ring.mean() < 0.5, (cls, ring.mean())  # five spokes, dark between
            assert np.count_nonzero(np.diff(np.r_[ring, ring[0]].astype(int)) == 1) == 5
        else:
            assert ring.mean() == 1.0


def test_part_boxes_are_cached_and_not_shared():
    """The planner asks for a ridden two-wheeler's part boxes in every frame of its track."""
    from assets_procedural.shapes import _part_box, part_box

    v, dims = sample_variant("motorcycle", np.random.default_rng(3))
    lo, hi = part_box("motorcycle", v)
    assert np.allclose(hi - lo, dims, atol=1e-4)  # the catalog's extent comes from the same box
    hits = _part_box.cache_info().hits
    lo[:] = 99.0  # the caller's copy
    lo2, hi2 = part_box("motorcycle", v)
    assert _part_box.cache_info().hits == hits + 1 and not np.allclose(lo2, 99.0)
    fresh = _part_box.__wrapped__("motorcycle", json.dumps(v, sort_keys=True), "all")
    assert np.array_equal(lo2, fresh[0]) and np.array_equal(hi2, fresh[1])
