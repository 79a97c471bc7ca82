"""The bpy builders: every class (all body types) and both twins, dims and materials."""

from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from assets_procedural.objects import build_object, remove_object  # noqa: E402
from assets_procedural.twin_builder import build_twin  # noqa: E402
from blendgen import CLASSES  # noqa: E402
from blendgen.plan import PlacedObject  # noqa: E402
from blendgen.scene.catalog import sample_variant  # noqa: E402
from blendgen.twin.model import load_twin  # noqa: E402

pytestmark = pytest.mark.bpy
TWINS = Path(__file__).resolve().parents[1] / "assets_procedural" / "twins"
KINDS = {"car": {"sedan", "hatchback", "suv", "van"}, "truck": {"box_truck", "semi", "pickup"},
         "bus": {"city", "midi"}, "person": {"standing", "walking"}, "bicycle": {"city", "road", "mountain"},
         "motorcycle": {"sport", "cruiser", "scooter"}, "traffic light": {"visor", "backplate"}}


def _bsdf(mat):
    return mat.node_tree.nodes["Principled BSDF"]


def _local_box(ob):
    v = np.array([tuple(x.co) for x in ob.data.vertices])
    return v.min(0), v.max(0)


def _variants():
    rng = np.random.default_rng(5)
    out = []
    for cls, kinds in KINDS.items():
        seen = {}
        for _ in range(400):
            v, d = sample_variant(cls, rng)
            key = (v["kind"], "rider" in v)
            seen.setdefault(key, (v, d))
        assert {k for k, _ in seen} == kinds, cls
        out += [(cls, v, d) for v, d in seen.values()]
    return out


def test_every_class_and_body_type_builds_to_its_dims():
    for i, (cls, v, d) in enumerate(_variants(), start=1):
        o = PlacedObject(i, cls, (3.0, -2.0, 0.15), 0.7, d, v, state="green" if cls == "traffic light" else None)
        root = build_object(o)
        lo, hi = _local_box(root)
        np.testing.assert_allclose(hi - lo, d, atol=2e-3, err_msg=f"{cls} {v['kind']}")
        np.testing.assert_allclose([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]], 0.0, atol=2e-3)
        assert tuple(root.location) == pytest.approx((3.0, -2.0, 0.15))
        assert root.rotation_euler[2] == pytest.approx(0.7)
        for ob in [root, *root.children_recursive]:
            if ob.type == "MESH":
                assert ob.pass_index == i
        assert np.isfinite(np.array([tuple(x.co) for x in root.data.vertices])).all()
        names = [m.name.split("_")[0] for m in root.data.materials]
        if cls in ("car", "truck", "bus"):
            assert {"paint", "glass", "rubber"} <= set(names)
            paint = next(m for m in root.data.materials if m.name.startswith("paint"))
            assert _bsdf(paint).inputs["Coat Weight"].default_value == 1.0  # clear coat
            assert any(n in names for n in ("alloy", "chrome"))
        if cls == "person" or "rider" in v:
            skin = next(m for m in root.data.materials if m.name.startswith("skin"))
            assert _bsdf(skin).inputs["Subsurface Weight"].default_value > 0
            fabric = next(m for m in root.data.materials if m.name.startswith("fabric"))
            assert _bsdf(fabric).inputs["Sheen Weight"].default_value > 0
        if cls in ("bicycle", "motorcycle"):
            assert {"rubber", "chrome"} <= set(names)
        if cls == "traffic light":
            lamps = {m.name: _bsdf(m).inputs["Emission Strength"].default_value
                     for m in root.data.materials if m.name.startswith("lamp")}
            lit = [n for n, s in lamps.items() if s > 1.0]
            assert len(lamps) == 3 and len(lit) == 1
            col = _bsdf(bpy.data.materials[lit[0]]).inputs["Emission Color"].default_value
            assert col[1] > col[0]  # green lit
        remove_object(root)


def test_traffic_light_states_light_the_right_lamp():
    v, d = sample_variant("traffic light", np.random.default_rng(1))
    for k, state in enumerate(("red", "amber", "green")):
        root = build_object(PlacedObject(100 + k, "traffic light", (0, 0, 2.6), 0.0, d, v, state=state))
        lit = [m for m in root.data.materials
               if m.name.startswith("lamp") and _bsdf(m).inputs["Emission Strength"].default_value > 1.0]
        r, g, _, _ = _bsdf(lit[0]).inputs["Emission Color"].default_value
        assert {"red": r > 0.9 and g < 0.1, "amber": r > 0.9 and 0.2 < g < 0.7, "green": g > 0.9}[state]
        # the lit lamp sits at the right height: red on top, green at the bottom
        idx = [i for i, m in enumerate(root.data.materials) if m == lit[0]][0]
        zs = [p.center.z for p in root.data.polygons if p.material_index == idx]
        frac = np.mean(zs) / d[2]
        assert {"red": frac > 0.6, "amber": 0.35 < frac < 0.65, "green": frac < 0.4}[state]
        remove_object(root)


def test_removed_objects_leave_no_meshes():
    before = len(bpy.data.meshes)
    rng = np.random.default_rng(3)
    for i in range(10):
        cls = list(CLASSES)[i % 7]
        v, d = sample_variant(cls, rng)
        remove_object(build_object(PlacedObject(i + 1, cls, (0, 0, 0), 0.0, d, v)))
    assert len(bpy.data.meshes) == before


def test_object_without_variant_still_builds_to_dims():
    root = build_object(PlacedObject(7, "car", (0, 0, 0), 0.0, (4.5, 1.8, 1.5)))
    lo, hi = _local_box(root)
    np.testing.assert_allclose(hi - lo, (4.5, 1.8, 1.5), atol=2e-3)
    remove_object(root)


@pytest.mark.parametrize("name", ["demo_town", "highway"])
def test_twin_builds_with_roles_and_materials(name):
    twin = load_twin(TWINS / f"{name}.yaml")
    info = build_twin(twin)
    assert info["build_s"] < 15.0
    coll = bpy.data.collections[info["collection"]]
    roles = {ob.name: ob.get("blendgen_role") for ob in coll.objects}
    assert set(roles.values()) <= {"road", "marking", "sidewalk", "structure", "vegetation"}
    assert all(r is not None for r in roles.values())
    want = {"road", "marking", "structure", "vegetation"} | ({"sidewalk"} if name == "demo_town" else set())
    assert want <= set(roles.values())
    mats = {m.name.split("_")[0] for ob in coll.objects if ob.type == "MESH" for m in ob.data.materials}
    assert {"asphalt", "marking", "ground"} <= {m.rstrip("0123456789.") for m in mats}
    road = next(ob for ob in coll.objects if ob.name.startswith("road_"))
    asphalt = road.data.materials[0]
    assert any(n.bl_idname == "ShaderNodeTexNoise" for n in asphalt.node_tree.nodes)  # wear patches
    marks = next(ob for ob in coll.objects if ob.name.split(".")[0] == "markings")  # .001 after an earlier build
    z = np.array([v.co.z for v in marks.data.vertices])
    assert z.min() > 0.0 and z.max() < 0.02  # painted on the asphalt
    if name == "demo_town":
        bld = [ob for ob in coll.objects if ob.get("blendgen_kind") == "building"]
        assert len(bld) == len(twin.spec.buildings)
        facade = bld[0].data.materials[0]
        assert any(n.bl_idname == "ShaderNodeMixShader" for n in facade.node_tree.nodes)  # windows
        b0 = twin.spec.buildings[0]
        lo, hi = _local_box(bld[0])
        assert hi[2] == pytest.approx(b0.height_m + 0.4)
        side = next(ob for ob in coll.objects if ob.name.startswith("sidewalk_"))
        zs = np.array([v.co.z for v in side.data.vertices])
        assert zs.max() == pytest.approx(0.15, abs=0.01)  # curb height
        # sidewalk tops never lie on a carriageway (cut at the crossing road)
        top = [side.matrix_world @ p.center for p in side.data.polygons if p.normal.z > 0.9 or p.normal.z < -0.9]
        on_road = [twin.on_road(c.x, c.y) for c in top[:: max(1, len(top) // 300)]]
        assert np.mean(on_road) < 0.02
    for ob in list(coll.objects):
        bpy.data.objects.remove(ob, do_unlink=True)


def test_ridden_two_wheelers_build_as_vehicle_and_person():
    from blendgen.scene.riders import split_rider

    rng = np.random.default_rng(8)
    for cls in ("bicycle", "motorcycle"):
        v, d = next((v, d) for v, d in iter(lambda: sample_variant(cls, rng), None) if "rider" in v)
        vehicle, rider = split_rider(PlacedObject(20, cls, (5.0, 1.0, 0.0), 0.4, d, v), 21)
        for o, must, mustnt in ((vehicle, "rubber", "skin"), (rider, "skin", "rubber")):
            root = build_object(o)
            lo, hi = _local_box(root)
            np.testing.assert_allclose(hi - lo, o.dims, atol=2e-3, err_msg=f"{cls} {o.cls}")
            assert root.pass_index == o.id
            names = {m.name.split("_")[0] for m in root.data.materials}
            assert must in names and mustnt not in names, (cls, o.cls, names)
            remove_object(root)


def test_vehicle_lamps_switch_on_at_night():
    from assets_procedural.materials import set_vehicle_lamps

    v, d = sample_variant("car", np.random.default_rng(2))
    root = build_object(PlacedObject(30, "car", (0, 0, 0), 0.0, d, v))
    lamps = {m.name: m for m in root.data.materials if "blendgen_lamp" in m}
    assert {m["blendgen_lamp"] for m in lamps.values()} == {"head", "tail"}

    def strength():
        return {m["blendgen_lamp"]: _bsdf(m).inputs["Emission Strength"].default_value for m in lamps.values()}

    assert set_vehicle_lamps(True) >= 2
    on = strength()
    assert on["head"] > 20 and on["tail"] > 5
    set_vehicle_lamps(False)
    off = strength()
    assert off["head"] < 0.5 and off["tail"] < 0.5
    tail = next(m for m in lamps.values() if m["blendgen_lamp"] == "tail")
    r, g, b, _ = _bsdf(tail).inputs["Emission Color"].default_value
    assert r > 0.9 and g < 0.1 and b >= g  # red tail lights (orange when green > blue clips)
    remove_object(root)


def test_map_twin_road_meshes_follow_elevation(tmp_path):
    """An OpenDRIVE road with a 5 % slope and superelevation: the asphalt's vertices lie on
    the road surface the twin (and so the planner) uses."""
    from test_maps_relief import RELIEF

    f = tmp_path / "relief.xodr"
    f.write_text(RELIEF.replace("</lanes></road>", '</lanes><objects><object type="pole" id="9" s="150" t="-9" '
                                                   'height="6" length="0.3" width="0.3" hdg="0"/></objects></road>'))
    twin = load_twin(f)
    (pole,) = twin.spec.poles
    info = build_twin(twin)
    coll = bpy.data.collections[info["collection"]]
    road = next(ob for ob in coll.objects if ob.name.startswith("road_1"))
    v = np.array([list(road.matrix_world @ x.co) for x in road.data.vertices])
    want = twin.ground_heights(v[:, :2])
    assert v[:, 2].max() > 7.0 and np.abs(v[:, 2] - want).max() < 0.02
    marks = next(ob for ob in coll.objects if ob.name.split(".")[0] == "markings")
    m = np.array([list(marks.matrix_world @ x.co) for x in marks.data.vertices])
    assert np.all((m[:, 2] - twin.ground_heights(m[:, :2]) > 0.0) & (m[:, 2] - twin.ground_heights(m[:, :2]) < 0.03))
    # street furniture stands on the sloped ground (not at z = 0)
    fur = next(ob for ob in coll.objects if ob.name.split(".")[0] == "street_furniture")
    p = np.array([list(fur.matrix_world @ x.co) for x in fur.data.vertices])
    near = np.hypot(p[:, 0] - pole.position[0], p[:, 1] - pole.position[1]) < 0.3
    assert abs(p[near, 2].min() - twin.ground_height(*pole.position)) < 0.01 and p[near, 2].min() > 6.0


def test_parked_two_wheelers_lean_on_a_side_stand():
    from assets_procedural.shapes import PARKED_LEAN_DEG, build_shape
    from blendgen.scene.riders import split_rider

    def tyre_lean_deg(mb):
        """Tilt of the tyres off vertical, towards +y (the side stand's side)."""
        rubber = mb.slots.index("rubber")
        idx = sorted({i for f, m in zip(mb.faces, mb.mat) if m == rubber for i in f})
        v = mb.vertices[idx]
        slope = np.polyfit(v[:, 2], v[:, 1], 1)[0]
        return np.degrees(np.arctan(slope))

    rng = np.random.default_rng(5)
    for cls in ("bicycle", "motorcycle"):
        v, d = next((v, d) for v, d in iter(lambda: sample_variant(cls, rng), None) if "rider" not in v)
        mb = build_shape(cls, v, d)
        lo, hi = mb.vertices.min(0), mb.vertices.max(0)
        np.testing.assert_allclose(hi - lo, d, atol=1e-6)  # still exactly its catalog box
        assert 0.7 * PARKED_LEAN_DEG < tyre_lean_deg(mb) < 1.1 * PARKED_LEAN_DEG, cls
        # a ridden one stays upright
        v, d = next((v, d) for v, d in iter(lambda: sample_variant(cls, rng), None) if "rider" in v)
        vehicle, _ = split_rider(PlacedObject(20, cls, (5.0, 1.0, 0.0), 0.4, d, v), 21)
        assert abs(tyre_lean_deg(build_shape(cls, vehicle.variant, vehicle.dims))) < 0.5, cls
