"""Labels: instances from the id image, the per-frame file, and COCO / YOLO / KITTI round-trips."""

import cv2
import numpy as np
import pytest
from pycocotools import mask as mask_utils
from pycocotools.coco import COCO

from blendgen import CLASSES
from blendgen.errors import UserError
from blendgen.frame_labels import find_frame_labels, read_frame_labels, write_frame_labels
from blendgen.labels.export import export_labels
from blendgen.labels.instances import decode_mask, extract_instances
from blendgen.labels.kitti import DEVKIT_TYPES, KITTI_TYPES, parse_label_line
from blendgen.labels.yolo import NAMES

from labels_fixtures import CAMERA, H, W, hull_mask, make_frame, synthetic_instances


@pytest.fixture(scope="module")
def frame():
    index, plan, amodal = make_frame()
    inst = extract_instances(index, plan, CAMERA, amodal_px=amodal, min_visible_px=1, small_objects="drop")
    return index, plan, amodal, {i["id"]: i for i in inst}


def test_boxes_tight_to_masks_and_masks_exact(frame):
    index, _, _, inst = frame
    assert set(inst) == {1, 2, 3, 4}  # id 5 is planned but outside the view
    for oid, i in inst.items():
        m = decode_mask(i["segmentation"])
        assert np.array_equal(m.astype(bool), index == oid)
        ys, xs = np.nonzero(m)
        assert i["bbox"] == [xs.min(), ys.min(), xs.max() - xs.min() + 1, ys.max() - ys.min() + 1]
        assert mask_utils.toBbox({**i["segmentation"], "counts": i["segmentation"]["counts"].encode()}).tolist() == i["bbox"]
        assert i["area"] == int(m.sum()) == i["visible_px"]
        assert i["category_id"] == CLASSES[i["cls"]]
        assert i["track_id"] == oid
    assert inst[4]["bbox"] == [150, 5, 1, 1] and inst[4]["area"] == 1


def test_occlusion_matches_hidden_pixels(frame):
    index, plan, amodal, inst = frame
    car, person = plan.objects[0], plan.objects[1]
    hidden = int((hull_mask(person) & hull_mask(car)).sum())
    assert hidden > 0, "fixture: the person must be partly behind the car"
    expected = hidden / hull_mask(person).sum()
    assert inst[2]["occlusion"] == pytest.approx(expected, abs=1e-12)
    assert inst[1]["occlusion"] == pytest.approx(0.0, abs=1e-12)
    assert 0.0 < inst[2]["occlusion"] < 1.0


def test_truncation_at_image_border(frame):
    _, plan, _, inst = frame
    truck = plan.objects[2]
    pad = 400
    full = hull_mask(truck, pad=pad)
    inside = full[pad:pad + H, pad:pad + W].sum()
    expected = 1.0 - inside / full.sum()
    assert 0.2 < expected < 0.95, "fixture: the truck must be cut by the left border"
    assert inst[3]["truncation"] == pytest.approx(expected, abs=0.02)
    assert inst[1]["truncation"] == pytest.approx(0.0, abs=1e-6)
    assert inst[3]["bbox"][0] == 0  # touches the border


def test_box3d_in_camera_frame(frame):
    _, plan, _, inst = frame
    car = inst[1]["box3d_cam"]
    # World (12, 0.5, 0) seen from (0, 0, 1.5) looking along +x: cam x = -0.5, y = 1.5, z = 12.
    assert np.allclose(car["location"], [-0.5, 1.5, 12.0], atol=1e-9)
    assert car["dimensions_hwl"] == [1.5, 1.8, 4.5]
    # Driving away from the camera is ry = -pi/2 in KITTI; yaw 0.3 turns forward toward world +y
    # = camera -x: forward = (-sin .3, 0, cos .3) -> ry = atan2(-cos .3, -sin .3) = -(pi/2 + .3).
    assert car["rotation_y"] == pytest.approx(-(np.pi / 2 + 0.3), abs=1e-9)
    corners = np.asarray(car["corners"])
    assert corners.shape == (8, 3)
    assert inst[1]["distance_m"] == pytest.approx(np.linalg.norm(corners.mean(0)))
    assert np.isfinite(corners).all()


def test_small_objects_drop_or_ignore():
    index, plan, amodal = make_frame()
    dropped = extract_instances(index, plan, CAMERA, amodal_px=amodal, min_visible_px=2, small_objects="drop")
    assert 4 not in {i["id"] for i in dropped}
    kept = extract_instances(index, plan, CAMERA, amodal_px=amodal, min_visible_px=2, small_objects="ignore")
    flags = {i["id"]: i["ignore"] for i in kept}
    assert flags[4] is True and flags[1] is False
    none = extract_instances(np.zeros((H, W), np.int32), plan, CAMERA, amodal_px=None, min_visible_px=0,
                             small_objects="drop")
    assert none == []


def test_object_behind_camera_is_stable():
    index, plan, _ = make_frame()
    from blendgen.plan import PlacedObject

    # A long bus reaching from behind the camera into view on the right.
    plan.objects.append(PlacedObject(6, "bus", (0.0, -3.0, 0.0), 0.0, (14.0, 2.5, 3.2)))
    index = index.copy()
    index[40:90, 140:160] = 6
    inst = {i["id"]: i for i in extract_instances(index, plan, CAMERA, amodal_px=None, min_visible_px=1,
                                                  small_objects="drop")}
    t = inst[6]["truncation"]
    assert np.isfinite(t) and 0.5 < t <= 1.0
    assert inst[6]["occlusion"] is None


def test_bad_inputs_name_the_problem(tmp_path):
    index, plan, amodal = make_frame()
    with pytest.raises(UserError, match="f000001.*integer"):
        extract_instances(index.astype(float), plan, CAMERA, amodal_px=amodal, min_visible_px=1,
                          small_objects="drop")
    with pytest.raises(UserError, match="aspect"):
        extract_instances(np.zeros((90, 90), np.int32), plan, CAMERA, amodal_px=None, min_visible_px=1,
                          small_objects="drop")
    plan.objects[0].position = (float("nan"), 0.0, 0.0)
    with pytest.raises(UserError, match="f000001: object 1 .*non-finite"):
        extract_instances(index, plan, CAMERA, amodal_px=amodal, min_visible_px=1, small_objects="drop")
    p = tmp_path / "labels.json"
    p.write_text('{"format": "blendgen-frame-labels", "version": 1, "frame_id": "a", "image": "x.png", '
                 '"width": 10, "height": 10, "instances": [{"id": 1}]}')
    with pytest.raises(UserError, match=r"labels.json: instances\[0\].*cls"):
        read_frame_labels(p)
    p.write_text("{broken")
    with pytest.raises(UserError, match="labels.json.*JSON"):
        read_frame_labels(p)


def _write_out(tmp_path, n_frames=3, seed=0):
    rng = np.random.default_rng(seed)
    out = tmp_path / "out"
    index, plan, amodal = make_frame()
    for k in range(n_frames):
        fid = f"f{k:06d}"
        d = out / "frames" / fid
        d.mkdir(parents=True)
        cv2.imwrite(str(d / "composite.png"), np.full((H, W, 3), 40 * k, np.uint8))
        if k == 0:
            inst = extract_instances(index, plan, CAMERA, amodal_px=amodal, min_visible_px=2,
                                     small_objects="ignore")
        else:
            inst = synthetic_instances(rng, 5)
        write_frame_labels(d / "labels.json", fid, "composite.png", W, H, inst, camera=CAMERA)
    return out


def test_frame_labels_round_trip(tmp_path):
    out = _write_out(tmp_path, 1)
    doc = read_frame_labels(out / "frames/f000000/labels.json")
    assert doc["frame_id"] == "f000000" and doc["width"] == W and doc["height"] == H
    assert doc["image_path"] == (out / "frames/f000000/composite.png").resolve()
    assert {i["id"] for i in doc["instances"]} == {1, 2, 3, 4}


def test_export_round_trips(tmp_path):
    out = _write_out(tmp_path, 3)
    paths = find_frame_labels(out)
    summary = export_labels(out, paths, ["coco", "yolo", "kitti"])
    frames = [read_frame_labels(p) for p in paths]
    n_inst = sum(len(f["instances"]) for f in frames)
    assert summary["frames"] == 3 and summary["instances"] == n_inst

    # COCO: pycocotools loads it; every box equals the box of its decoded mask.
    coco = COCO(str(out / "labels/coco.json"))
    assert sorted(coco.getCatIds()) == sorted(CLASSES.values())
    assert len(coco.getAnnIds()) == n_inst
    for ann in coco.loadAnns(coco.getAnnIds()):
        m = coco.annToMask(ann)
        assert m.sum() == ann["area"]
        assert mask_utils.toBbox(mask_utils.encode(np.asfortranarray(m))).tolist() == ann["bbox"]
        img = coco.loadImgs(ann["image_id"])[0]
        assert (out / img["file_name"]).exists()
    assert any(a["iscrowd"] for a in coco.loadAnns(coco.getAnnIds()))  # the ignored 1-pixel object

    # YOLO: boxes and polygons normalised, class index in NAMES, images resolvable.
    y = out / "labels/yolo"
    assert "names:" in (y / "data.yaml").read_text() and (y / "seg/data.yaml").exists()
    for fr in frames:
        keep = [i for i in fr["instances"] if not i["ignore"]]
        rows = [l.split() for l in (y / "labels" / f"{fr['frame_id']}.txt").read_text().splitlines()]
        assert len(rows) == len(keep)
        for r, i in zip(rows, keep):
            c, cx, cy, w, h = int(r[0]), *map(float, r[1:])
            x0, y0, bw, bh = i["bbox"]
            assert NAMES[c] == i["cls"]
            assert (cx - w / 2) * W == pytest.approx(x0, abs=1e-3) and (cy - h / 2) * H == pytest.approx(y0, abs=1e-3)
            assert w * W == pytest.approx(bw, abs=1e-3) and h * H == pytest.approx(bh, abs=1e-3)
        segs = [l.split() for l in (y / "seg/labels" / f"{fr['frame_id']}.txt").read_text().splitlines()]
        for s, i in zip(segs, keep):
            pts = np.array(s[1:], float).reshape(-1, 2) * [W, H]
            assert len(pts) >= 3 and (pts >= 0).all()
            x0, y0, bw, bh = i["bbox"]
            # The polygon through pixel centres lies inside the box and reaches within 1 px of each side.
            assert pts[:, 0].min() == pytest.approx(x0 + 0.5, abs=0.51) and pts[:, 0].max() <= x0 + bw + 1e-3
            assert pts[:, 1].min() == pytest.approx(y0 + 0.5, abs=0.51) and pts[:, 1].max() <= y0 + bh + 1e-3
        assert (y / "images" / f"{fr['frame_id']}.png").exists()
        assert cv2.imread(str(y / "images" / f"{fr['frame_id']}.png")) is not None
    assert len((y / "train.txt").read_text().splitlines()) == 3

    # KITTI: one line per instance, ignored as DontCare, box and 3D box as in the labels.
    for fr in frames:
        lines = (out / "labels/kitti/label_2" / f"{fr['frame_id']}.txt").read_text().splitlines()
        assert len(lines) == len(fr["instances"])
        for line, i in zip(lines, fr["instances"]):
            k = parse_label_line(line)
            x0, y0, bw, bh = i["bbox"]
            assert k["bbox"] == pytest.approx([x0, y0, x0 + bw, y0 + bh], abs=0.006)
            if i["ignore"] or KITTI_TYPES["kitti"][i["cls"]] == "DontCare":
                assert k["type"] == "DontCare"
            else:
                assert k["location"] == pytest.approx(i["box3d_cam"]["location"], abs=0.006)
                assert k["dimensions_hwl"] == pytest.approx(i["box3d_cam"]["dimensions_hwl"], abs=0.006)
        calib = (out / "labels/kitti/calib" / f"{fr['frame_id']}.txt").read_text()
        P2 = np.array(calib.splitlines()[2].split()[1:], float).reshape(3, 4)
        assert np.allclose(P2[:, :3], CAMERA.K)

    # Re-export is identical (deterministic order).
    before = (out / "labels/coco.json").read_bytes()
    export_labels(out, list(reversed(paths)), ["coco"])
    assert (out / "labels/coco.json").read_bytes() == before


def check_devkit_line(line: str) -> str:
    """The KITTI object devkit's label format (readme.txt of devkit_object): 15 fields,
    one of its 9 types, truncated 0..1, occluded 0..3, alpha and rotation_y in [-pi, pi]
    (DontCare: -1 -1 -10 ... -1000 ... -10)."""
    f = line.split(" ")
    assert len(f) == 15, line
    assert f[0] in DEVKIT_TYPES, line
    v = [float(x) for x in f[1:]]
    if f[0] == "DontCare":
        assert v[:3] == [-1, -1, -10] and v[7:] == [-1, -1, -1, -1000, -1000, -1000, -10], line
    else:
        assert 0 <= v[0] <= 1 and int(f[2]) in (0, 1, 2, 3) and f[2].isdigit(), line
        assert -np.pi - 0.01 <= v[2] <= np.pi + 0.01 and -np.pi - 0.01 <= v[13] <= np.pi + 0.01, line
        assert min(v[7:10]) > 0, line  # h w l
    assert v[3] <= v[5] and v[4] <= v[6], line  # left <= right, top <= bottom
    return f[0]


def test_kitti_types_pass_the_devkit_format(tmp_path):
    """Issue 16: the default KITTI export uses only KITTI's types; 'extended' keeps ours."""
    out = _write_out(tmp_path, 4)
    s = export_labels(out, find_frame_labels(out), ["kitti"])
    assert s["kitti"]["types"] == "kitti" and s["kitti"]["type_of_class"]["bicycle"] == "Misc"
    types = [check_devkit_line(line) for p in sorted((out / "labels/kitti/label_2").glob("*.txt"))
             for line in p.read_text().splitlines()]
    assert len(types) > 4 and {"Car", "Pedestrian"} <= set(types)
    export_labels(out, find_frame_labels(out), ["kitti"], kitti_types="extended")
    ext = {ln.split()[0] for p in (out / "labels/kitti/label_2").glob("*.txt") for ln in p.read_text().splitlines()}
    assert ext - set(DEVKIT_TYPES)  # e.g. Bicycle, Bus: descriptive, not KITTI's


def test_yolo_split_by_frame_is_seeded(tmp_path):
    out = _write_out(tmp_path, 10)
    s = export_labels(out, find_frame_labels(out), ["yolo"], yolo_val_fraction=0.3, seed=4)
    y = out / "labels/yolo"
    train, val = ((y / f).read_text().splitlines() for f in ("train.txt", "val.txt"))
    assert (s["yolo"]["train_frames"], s["yolo"]["val_frames"]) == (7, 3) and len(val) == 3
    assert not set(train) & set(val) and len(set(train) | set(val)) == 10
    assert "val: val.txt" in (y / "data.yaml").read_text() and (y / "seg/val.txt").read_text().splitlines() == val
    export_labels(out, find_frame_labels(out), ["yolo"], yolo_val_fraction=0.3, seed=4)
    assert (y / "val.txt").read_text().splitlines() == val  # same seed, same split
    export_labels(out, find_frame_labels(out), ["yolo"], yolo_val_fraction=0.3, seed=5)
    assert (y / "val.txt").read_text().splitlines() != val
    export_labels(out, find_frame_labels(out), ["yolo"])
    assert not (y / "val.txt").exists() and "val: train.txt" in (y / "data.yaml").read_text()


def test_export_rejects_unknown_format_and_missing_image(tmp_path):
    out = _write_out(tmp_path, 1)
    with pytest.raises(UserError, match="export.formats.*pascal"):
        export_labels(out, find_frame_labels(out), ["pascal"])
    (out / "frames/f000000/composite.png").unlink()
    with pytest.raises(UserError, match="labels.json.*composite.png"):
        export_labels(out, find_frame_labels(out), ["coco"])


def test_ridden_bicycle_gives_a_person_and_a_bicycle_instance():
    from blendgen.labels.kitti import label_line
    from blendgen.plan import FramePlan, PlacedObject
    from blendgen.scene.catalog import sample_variant
    from blendgen.scene.riders import split_rider
    from labels_fixtures import T_WORLD_CAM

    rng = np.random.default_rng(4)
    v, d = next((v, d) for v, d in iter(lambda: sample_variant("bicycle", rng), None) if "rider" in v)
    bike, rider = split_rider(PlacedObject(7, "bicycle", (8.0, 0.5, 0.0), 1.5, d, v, velocity=(0.0, 5.0, 0.0)), 8)
    assert (bike.id, bike.cls, rider.id, rider.cls) == (7, "bicycle", 8, "person")
    assert rider.variant["rides"] == 7 and rider.velocity == bike.velocity and "rider" in bike.variant
    assert bike.dims[2] < d[2] - 0.4 and rider.dims[2] > 1.2  # the rider is no longer in the bike's box
    parked, = split_rider(PlacedObject(9, "bicycle", (8.0, 0.5, 0.0), 1.5, *sample_parked(rng)), 10)
    assert parked.cls == "bicycle" and parked.id == 9
    index = np.zeros((H, W), np.int32)
    for o in (bike, rider):  # the rider in front of the frame where they overlap
        index[hull_mask(o)] = o.id
    plan = FramePlan("f000002", 0.0, T_WORLD_CAM.tolist(), [bike, rider])
    inst = {i["id"]: i for i in extract_instances(index, plan, CAMERA, min_visible_px=1, small_objects="drop")}
    assert set(inst) == {7, 8}
    assert (inst[7]["cls"], inst[8]["cls"]) == ("bicycle", "person")
    assert inst[8]["rides"] == {"id": 7, "cls": "bicycle"} and inst[7]["rides"] is None
    assert inst[8]["bbox"][1] < inst[7]["bbox"][1]  # the person's box reaches higher than the bike's
    assert label_line(inst[8]).split()[0] == "Cyclist" and label_line(inst[7]).split()[0] == "Misc"
    assert label_line(inst[7], "extended").split()[0] == "Bicycle"


def sample_parked(rng):
    from blendgen.scene.catalog import sample_variant

    while True:
        v, d = sample_variant("bicycle", rng)
        if "rider" not in v:
            return d, v
