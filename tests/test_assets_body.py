"""People from MakeHuman's body (assets_procedural/body.py; NumPy only, no bpy)."""


import numpy as np
import pytest

from assets_procedural import body
from assets_procedural.meshkit import MeshBuilder
from assets_procedural.shapes import figure, walking_legs
from blendgen.scene.catalog import sample_variant


def _regions(mb: MeshBuilder) -> dict[str, np.ndarray]:
    """Vertices per material slot."""
    v, mat = mb.vertices, np.asarray(mb.mat)
    return {slot: v[np.unique(np.concatenate([mb.faces[i] for i in np.flatnonzero(mat == k)]))]
            for k, slot in enumerate(mb.slots)}


def test_body_data_is_consistent():
    d = body.human()
    w = d["body_w"].astype(float)
    assert w.shape == (len(d["body_v"]), len(d["parts"]))
    np.testing.assert_allclose(w.sum(1), 1.0, atol=2e-3)
    assert d["body_v"][:, 2].min() == pytest.approx(0.0, abs=1e-6)
    assert 1.6 < d["body_v"][:, 2].max() < 1.75
    for g in d["garments"]:
        assert d[g + "_f"].max() < len(d[g + "_v"])
        np.testing.assert_allclose(d[g + "_w"].astype(float).sum(1), 1.0, atol=2e-3)
    # left is +y, forward is +x: the left hip and the toes
    J = dict(zip(d["joint_names"], d["joint_pos"]))
    assert J["hip.L"][1] > 0 > J["hip.R"][1]
    assert J["toe.L"][0] > J["ankle.L"][0] + 0.08


def test_outfit_and_shape_follow_the_variant_and_are_reproducible():
    v = {"seed": 7, "long_sleeves": True}
    assert body.outfit(v) == body.outfit(dict(v)) and body.shape(v) == body.shape(dict(v))
    assert body.outfit(v)[0] in body.TOPS_LONG
    assert body.outfit({"seed": 7, "long_sleeves": False})[0] in body.TOPS_SHORT
    assert body.outfit({"seed": 7, "skirt": True})[0] == body.SKIRT
    assert body.sex({"seed": 1, "skirt": True}) == "female"
    assert body.outfit({"seed": 7, "helmet": True})[2] is None
    people = [{"seed": s} for s in range(400)]
    assert 0.35 < np.mean([body.sex(p) == "female" for p in people]) < 0.55
    assert {body.outfit(p)[2] for p in people} == {h for hs in body.HAIR.values() for h in hs}
    assert body.shape({"seed": 19, "build": "broad"}) == {"male": 1.0, "male_maxweight": body.WEIGHT["broad"]}
    assert body.shape({"seed": 0, "build": "slim"}) == {"female": 1.0, "female_minweight": -body.WEIGHT["slim"]}


def test_no_one_wears_skin_tones_head_to_toe_and_motorcyclists_wear_jackets():
    """Tan or brown top and trousers together read as a bare mannequin on real photos."""
    from blendgen.scene.catalog import SKIN_LIKE

    def tan(c):
        return any(np.allclose(c, s, rtol=0.1) for s in SKIN_LIKE)

    rng = np.random.default_rng(0)
    people = [sample_variant("person", rng)[0] for _ in range(400)]
    riders = [v["rider"] for v in (sample_variant("motorcycle", rng)[0] for _ in range(300)) if "rider" in v]
    assert not any(tan(p["shirt"]) and tan(p["pants"]) for p in people + riders)
    assert sum(tan(p["shirt"]) for p in people) > 20  # tan tops stay, with other trousers
    black = np.mean([max(r["shirt"]) < 0.02 for r in riders])
    assert 0.35 < black < 0.55  # riding jackets, mostly black
    # helmets: black, white or grey mostly, whatever the bike's paint; fixed per two-wheeler
    from blendgen.scene.catalog import helmet_colour

    bikes = [sample_variant("motorcycle", rng)[0] for _ in range(300)]
    helmets = [helmet_colour(b) for b in bikes]
    assert helmets == [helmet_colour(b) for b in bikes]
    neutral = np.mean([max(h) - min(h) < 0.05 for h in helmets])
    assert neutral > 0.75 and not any(tan(h) for h in helmets)


def test_shapes_change_the_body_where_expected():
    """A man is broader at the shoulders than a woman, a heavier body deeper at the waist."""
    d = body.human()
    J = {g: dict(zip(d["joint_names"], body._shaped("joint_pos", {g: 1.0}))) for g in ("male", "female")}
    for g in J:  # to one height
        s = 1.0 / body._shaped("body_v", {g: 1.0})[:, 2].max()
        J[g] = {k: p * s for k, p in J[g].items()}
    assert J["male"]["shoulder.L"][1] > J["female"]["shoulder.L"][1] + 0.005
    belly = (np.abs(d["body_v"][:, 2] - 1.0) < 0.02) & (np.abs(d["body_v"][:, 1]) < 0.12)

    def depth(alpha):  # front to back at the waist
        return np.ptp(body._shaped("body_v", alpha)[belly, 0])
    assert depth({"male": 1, "male_maxweight": 1}) > depth({"male": 1}) + 0.02
    assert depth({"male": 1}) > depth({"male": 1, "male_minweight": 1}) + 0.01


def _person(h=1.75, **kw):
    mb = MeshBuilder()
    figure(mb, {"seed": 3, "height_m": h, "long_sleeves": True, **kw})
    return mb


def test_standing_person_stands_on_both_feet_at_its_height():
    mb = _person()
    v = mb.vertices
    assert np.isfinite(v).all()
    shoes = _regions(mb)["shoes"]
    lo = v[:, 2].min()
    for side in (shoes[:, 1] > 0, shoes[:, 1] < 0):  # both soles on the ground
        assert shoes[side, 2].min() - lo < 0.01
    # feet under the hips (the rest A-pose stands 0.4 m wide), arms down beside the body
    assert np.ptp(shoes[:, 1]) < 0.42
    assert np.ptp(v[:, 1]) < 0.62
    body_h = v[:, 2].max() - lo
    assert 1.75 < body_h < 1.75 + 0.08  # crown plus hair and shoe soles
    # the garments hide what they cover: fewer skin faces than the whole body
    assert len(_regions(mb)["skin"]) < 0.8 * len(body.human()["body_v"])


def test_walking_person_swings_opposite_arm_and_leg():
    mb = _person(stride_rad=0.35)
    r = _regions(mb)
    shoes = r["shoes"]
    left, right = shoes[shoes[:, 1] > 0], shoes[shoes[:, 1] < 0]
    assert left[:, 0].max() > right[:, 0].max() + 0.3  # the left foot ahead
    skin = r["skin"]
    low = skin[skin[:, 2] < 1.0]  # hands
    assert low[low[:, 1] < 0, 0].max() > low[low[:, 1] > 0, 0].max() + 0.1  # the right hand ahead
    # the trailing leg pushes off: its heel up, its knee bent; the leading leg straight, its sole
    # on the ground (both straight read as a pair of compasses on the real photos)
    assert right[:, 2].max() > left[:, 2].max() + 0.03
    assert left[:, 2].min() - mb.vertices[:, 2].min() < 0.01
    J = body.rest_joints({"seed": 3}, 1.75)
    pelvis, target = walking_legs(J, 0.35, 1.75)

    def knee_deg(s):
        hip = pelvis + J["hip." + s] - J["pelvis"]
        a, b = target["knee." + s] - hip, target["ankle." + s] - target["knee." + s]
        return np.degrees(np.arccos(a @ b / np.linalg.norm(a) / np.linalg.norm(b)))
    assert knee_deg("L") < 2 and knee_deg("R") > 15


@pytest.mark.parametrize("cls", ["bicycle", "motorcycle"])
def test_rider_holds_the_grips_and_sits_on_the_seat(cls):
    rng = np.random.default_rng(5)
    v, d = next((v, d) for v, d in iter(lambda: sample_variant(cls, rng), None) if "rider" in v)
    calls = {}

    def capture(mb, rv, joints=None):  # the joints the vehicle builder asks for
        calls["joints"] = joints
        return figure(mb, rv, joints)

    import assets_procedural.shapes as shapes
    orig = shapes.figure
    shapes.figure = capture
    try:
        mb = MeshBuilder()
        shapes.BUILDERS[cls](mb, {**v, "part": "rider"}, *v["shape_dims"])
    finally:
        shapes.figure = orig
    j = calls["joints"]
    skin = _regions(mb)["skin"]
    for grip in j["hands"]:
        assert np.linalg.norm(skin - grip, axis=1).min() < 0.06  # the palm on the grip
    shoes = _regions(mb)["shoes"]
    for foot in j["feet"]:
        assert np.linalg.norm(shoes - foot, axis=1).min() < 0.08
    assert np.isfinite(mb.vertices).all()


@pytest.mark.parametrize("kind", ["sport", "cruiser", "scooter"])
def test_motorcycle_grips_are_where_a_rider_holds_them(kind):
    """Grips within 0.68 m ahead of the hips and at most 0.25 m above them, 0.6 m apart (a
    cruiser's 0.7 m): a scooter's bar 0.84 m ahead and 0.34 m up, a cruiser's 0.75 m ahead, and
    bars as wide as the box (0.9 m with the mirrors) had riders hold an arm out sideways."""
    import assets_procedural.shapes as shapes

    rng = np.random.default_rng(7)
    for _ in range(300):
        v, d = sample_variant("motorcycle", rng)
        if v["kind"] == kind and "rider" in v:
            break
    calls = {}
    orig = shapes.figure
    shapes.figure = lambda mb, rv, joints=None: calls.setdefault("joints", joints)
    try:
        shapes.BUILDERS["motorcycle"](MeshBuilder(), {**v, "W": 0.9, "part": "rider"}, d[0], 0.9, d[2])
    finally:
        shapes.figure = orig
    j = calls["joints"]
    pelvis, (left, right) = np.asarray(j["pelvis"]), np.asarray(j["hands"])
    for g in (left, right):
        assert 0.3 < g[0] - pelvis[0] < 0.68 and 0.0 < g[2] - pelvis[2] < 0.25, (g - pelvis)
    assert abs(left[1] - right[1]) <= (0.71 if kind == "cruiser" else 0.61)


def test_every_sampled_person_builds_finite_geometry():
    """The planner sizes every sampled person from its geometry (`catalog.shape_extent`)."""
    rng = np.random.default_rng(0)
    for _ in range(5):
        m = MeshBuilder()
        figure(m, sample_variant("person", rng)[0])
        assert len(m.vertices) > 0 and np.isfinite(m.vertices).all()
