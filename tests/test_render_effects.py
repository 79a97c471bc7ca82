"""Render driver, bpy-free parts: effect decisions, camera maths, rasteriser, EXR I/O."""

import subprocess
import sys

import numpy as np
import pytest

from blendgen.errors import UserError
from blendgen.geometry import Camera, R_world_cam_from_ypr, make_pose
from blendgen.job.schema import Render
from blendgen.plan import FramePlan, PlacedObject
from blendgen.render import effects as fx
from blendgen.render.exr import empty_passes, read_passes, write_passes
from blendgen.render.projection import blender_intrinsics, blender_matrix_world, make_canvas
from blendgen.render.raster import fill_triangles, rasterize_mask

CAM = Camera.from_hfov(640, 360, 70)
T = make_pose(R_world_cam_from_ypr(0.0), [0, 0, 1.5])  # looking along +x from 1.5 m
SUN = {"sun_direction": [0.3, 0.3, 0.9], "sun_strength": 3.0, "sun_color": [1, 1, 1], "sun_angle_deg": 0.5,
       "sky_color": [0.5, 0.6, 0.8], "sky_strength": 1.0, "sun_visible": True}
OVERCAST = {**SUN, "sun_strength": 0.0, "sun_visible": False}


def car(i, x, y, yaw=0.0, v=(0, 0, 0)):
    return PlacedObject(i, "car", (x, y, 0.0), yaw, (4.5, 1.8, 1.5), velocity=v)


def plan_of(*objs, lighting=SUN):
    return FramePlan("f000001", 0.0, T.tolist(), list(objs), lighting)


def test_bpy_free_modules_do_not_import_bpy():
    code = ("import sys, blendgen.render.exr, blendgen.render.effects, blendgen.render.projection, "
            "blendgen.render.raster, blendgen.render.passes; assert 'bpy' not in sys.modules, 'bpy imported'")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)


def test_passes_follow_outputs():
    assert fx.decide_passes({"index"}).value == ["index"]
    full = fx.decide_passes(set(fx.OUTPUTS)).value
    assert full[:4] == ["rgba", "index", "depth", "shadow_catcher"] and "glossy_color" in full
    with pytest.raises(ValueError, match="unknown render outputs"):
        fx.decide_passes({"rgba", "normals"})


def test_culling_keeps_visible_and_offscreen_shadow_casters():
    ahead, behind, far_left = car(1, 15, 0), car(2, -10, 0), car(3, 15, 60)
    kept, culled = fx.cull_objects(plan_of(ahead, behind, far_left), CAM, fx.sun_direction(SUN))
    assert [o.id for o in kept] == [1]
    assert "behind the camera" in culled[2] and "left of" in culled[3]
    # Just outside the left edge, its shadow (sun on the left: cast toward -y, into the view) keeps it.
    edge = car(4, 10, 10.5)
    Xc = fx._to_cam(T, edge.box_corners_world())
    assert fx.outside_frustum(CAM, Xc) is not None
    kept, _ = fx.cull_objects(plan_of(edge), CAM, np.array([0.0, 0.8, 0.6]))
    assert [o.id for o in kept] == [4]


def test_motion_blur_only_above_half_a_pixel():
    slow, fast = car(1, 20, 0, v=(0, 0.2, 0)), car(2, 20, 3, v=(0, 20.0, 0))
    s = fx.SHUTTER_LOW_LIGHT_S
    d, px = fx.decide_motion_blur([slow], CAM, T, s, "auto")
    assert d.value is False and px[1] < 0.5
    d, px = fx.decide_motion_blur([slow, fast], CAM, T, s, "auto")
    assert d.value is True and px[2] > 0.5 and "2" in d.reason
    assert fx.decide_motion_blur([fast], CAM, T, s, "off")[0].value is False
    assert fx.decide_motion_blur([car(3, 20, 0)], CAM, T, s, "on")[0].value is False


def test_motion_blur_is_relative_to_the_camera():
    """A car driving with the camera stays sharp; a parked one passes a moving camera."""
    v = (25.0, 0.0, 0.0)  # the camera drives along the road at 25 m/s
    with_traffic, parked = car(1, 15, 3.5, v=v), car(2, 15, 3.5)
    s = fx.SHUTTER_LOW_LIGHT_S
    d, px = fx.decide_motion_blur([with_traffic], CAM, T, s, "auto", cam_velocity=v)
    assert d.value is False and px[1] == 0.0
    d, px = fx.decide_motion_blur([parked], CAM, T, s, "auto", cam_velocity=v)
    assert d.value is True and px[2] > 0.5
    assert fx.blur_px(with_traffic, CAM, T, s) == fx.blur_px(parked, CAM, T, s, (-25.0, 0, 0))


def test_shutter_auto_follows_the_light():
    """A camera exposes short in daylight (the real video's poles are sharp at 32 m/s) and long
    at dusk and night; a number in the job is taken as it is."""
    day, night = {**SUN, "condition": "day"}, {**SUN, "condition": "night"}
    assert fx.shutter_for(Render(), day) == fx.SHUTTER_DAY_S == 0.001
    assert fx.shutter_for(Render(), night) == fx.shutter_for(Render(), None) == fx.SHUTTER_LOW_LIGHT_S
    assert fx.shutter_for(Render(shutter_s=0.02), day) == 0.02
    passing = car(1, 12, 4, v=(0.0, 0.0, 0.0))  # parked, the camera at 30 m/s
    plan = FramePlan("f000001", 0.0, T.tolist(), [passing], day, camera_velocity=(30.0, 0.0, 0.0))
    eff = fx.decide_effects(plan, CAM, Render(), {"rgba"})
    assert eff.shutter_s == 0.001
    long = fx.decide_effects(FramePlan("f000001", 0.0, T.tolist(), [passing], night, camera_velocity=(30.0, 0.0, 0.0)),
                             CAM, Render(), {"rgba"})
    assert long.shutter_s == fx.SHUTTER_LOW_LIGHT_S and long.blur_px[1] > 5 * eff.blur_px[1]


def test_shadow_catcher_sun_shadows_or_soft_contact_shadows():
    out = {"rgba", "shadow_catcher"}
    d = fx.decide_shadow_catcher(SUN, out)
    assert d.value is True and "sun is visible" in d.reason
    for light in (OVERCAST, {**SUN, "sun_direction": [1, 0, -0.1]}):  # overcast; sun below the horizon
        d = fx.decide_shadow_catcher(light, out)
        assert d.value is True and "soft shadow of the sky" in d.reason and fx.sun_direction(light) is None
    assert fx.decide_shadow_catcher({**OVERCAST, "sky_strength": 0.0}, out).value is False  # no light at all
    assert fx.decide_shadow_catcher(SUN, {"rgba"}).value is False
    # without a sun the catcher patch is the footprint grown by the margin, no cast shadow
    (patch,) = fx.catcher_patches([car(1, 15, 0)], fx.sun_direction(OVERCAST))
    m = fx.SOFT_MARGIN_M * 1.15 * 1.01
    assert np.ptp(patch[:, 0]) < 4.5 + 2 * m and np.ptp(patch[:, 1]) < 1.8 + 2 * m


def test_region_covers_object_and_its_shadow():
    obj = car(1, 15, 0)
    no_sun = fx.decide_region(plan_of(obj), [obj], CAM, None, True).value
    low_sun = np.array([-0.8, 0.0, 0.3]) / np.linalg.norm([-0.8, 0.0, 0.3])  # shadow away from camera
    with_shadow = fx.decide_region(plan_of(obj), [obj], CAM, low_sun, True).value
    uv, _ = CAM.project_world(T, obj.box_corners_world())
    x0, y0, x1, y1 = no_sun
    assert x0 <= uv[:, 0].min() and x1 >= uv[:, 0].max() and y0 <= uv[:, 1].min() and y1 >= uv[:, 1].max()
    assert (x1 - x0) * (y1 - y0) < 0.2 * CAM.width * CAM.height
    # The shadow lies farther away: it reaches up toward the horizon, above the car's base.
    shadow = fx.shadow_points(obj.box_corners_world(), low_sun, 0.0)
    suv, _ = CAM.project_world(T, shadow)
    assert with_shadow[1] <= suv[:, 1].min() and with_shadow[1] <= no_sun[1]
    assert fx.decide_region(plan_of(obj), [obj], CAM, None, False).value is None
    near = PlacedObject(2, "truck", (4.5, 0, 0), 0.0, (8.0, 2.5, 3.5))  # fills the view: full frame
    assert fx.decide_region(plan_of(near), [near], CAM, None, True).value is None
    # The catcher patch holds the footprint and the whole shadow.
    import cv2

    patch = fx.catcher_patches([obj], low_sun)[0]
    for p in np.concatenate([obj.box_corners_world(), shadow])[:, :2]:
        assert cv2.pointPolygonTest(patch[:, :2].astype(np.float32), tuple(map(float, p)), True) > 0.3
    assert np.allclose(patch[:, 2], 0.0)
    assert fx.border_fractions((64, 36, 320, 180), 640, 360) == pytest.approx((0.1, 0.5, 0.5, 0.9), abs=1e-5)


def test_empty_frame_is_skipped_and_decisions_serialise():
    import json

    eff = fx.decide_effects(plan_of(car(1, -20, 0)), CAM, Render(), {"rgba", "index"})
    assert eff.skip_render.value is True and eff.objects.value == []
    eff = fx.decide_effects(plan_of(car(1, 15, 0)), CAM, Render(samples=32, denoise=False), {"rgba", "index"})
    d = json.loads(json.dumps(eff.to_dict()))
    assert d["skip_render"]["value"] is False and d["sampling"]["value"]["samples"] == 32
    assert all(d[k]["reason"] for k in d)


def test_blender_intrinsics_match_the_viewplane_formula():
    for cam in (Camera(320, 180, 230.0, 240.0, 150.3, 95.7), Camera(180, 320, 250.0, 250.0, 92.0, 150.0),
                Camera(320, 180, 250.0, 230.0, 170.0, 80.0)):
        b = blender_intrinsics(cam)
        ax, ay = b["pixel_aspect"]
        ycor = ay / ax
        viewfac = cam.width if b["sensor_fit"] == "HORIZONTAL" else ycor * cam.height
        fx_ = viewfac * b["lens"] / b["sensor_width"]
        # Blender's viewplane (BKE_camera_params_compute_viewplane), back to OpenCV numbers.
        assert fx_ == pytest.approx(cam.fx) and fx_ / ycor == pytest.approx(cam.fy)
        assert (cam.width - 1) / 2 - b["shift_x"] * viewfac == pytest.approx(cam.cx)
        assert (cam.height - 1) / 2 + b["shift_y"] * viewfac / ycor == pytest.approx(cam.cy)
    M = blender_matrix_world(T)
    assert np.allclose(M[:3, 2], -T[:3, 2])  # Blender looks down its -z


@pytest.mark.parametrize("cam", [Camera(320, 180, 200.0, 200.0, 161.0, 88.0, [-0.25, 0.08, 0.001, -0.0005, 0.0]),
                                 Camera(320, 180, 150.0, 150.0, 160.3, 90.8, [0.043, 0.036, -0.034, 0.012],
                                        "equidistant")], ids=["radtan", "fisheye"])
def test_distortion_canvas_maps_agree_with_projection(cam):
    cv = make_canvas(cam)
    assert cv.remapped and cv.pinhole.width > cam.width and not cv.pinhole.distorted
    rng = np.random.default_rng(1)
    X = np.c_[rng.uniform(-0.6, 0.6, 50), rng.uniform(-0.35, 0.35, 50), np.ones(50)]
    uv_out, _ = cam.project(X)
    uv_pin, _ = cv.pinhole.project(X)
    ok = (uv_out[:, 0] > 1) & (uv_out[:, 0] < 318) & (uv_out[:, 1] > 1) & (uv_out[:, 1] < 178)
    # Bilinear lookup of the maps at the distorted pixel gives the pinhole pixel.
    import cv2

    mx = cv2.remap(cv.map_x, uv_out[ok, 0].astype(np.float32)[None], uv_out[ok, 1].astype(np.float32)[None],
                   cv2.INTER_LINEAR)[0]
    my = cv2.remap(cv.map_y, uv_out[ok, 0].astype(np.float32)[None], uv_out[ok, 1].astype(np.float32)[None],
                   cv2.INTER_LINEAR)[0]
    assert np.max(np.hypot(mx - uv_pin[ok, 0], my - uv_pin[ok, 1])) < 0.05
    assert np.all(np.isfinite(cv.map_x)) and np.all(np.isfinite(cv.map_y))
    plain = make_canvas(Camera.from_hfov(64, 36, 60))
    img = np.arange(64 * 36, dtype=np.float32).reshape(36, 64)
    assert not plain.remapped and plain.to_output(img) is img


def test_rasteriser_counts_pixel_centres():
    mask = np.zeros((20, 20), np.uint8)
    # Axis-aligned square [2.5, 12.5]^2 as two triangles: exactly the centres 3..12 -> 100 px.
    sq = np.array([[[2.5, 2.5], [12.5, 2.5], [12.5, 12.5]], [[2.5, 2.5], [12.5, 12.5], [2.5, 12.5]]])
    fill_triangles(mask, sq)
    assert mask.sum() == 100 and mask[3:13, 3:13].all()
    # Overlapping and opposite-winding triangles do not cancel (no even-odd rule).
    mask2 = np.zeros((20, 20), np.uint8)
    fill_triangles(mask2, np.concatenate([sq, sq[:, ::-1]]))
    assert mask2.sum() == 100
    # A 1 m square facing the camera at 10 m; and the same square straddling the camera plane.
    cam = Camera(200, 200, 100.0, 100.0, 99.5, 99.5)
    v = np.array([[-0.5, -0.5, 10], [0.5, -0.5, 10], [0.5, 0.5, 10], [-0.5, 0.5, 10]])
    m = rasterize_mask(cam, np.eye(4), v, np.array([[0, 1, 2], [0, 2, 3]]))
    assert m.sum() == 100
    v2 = np.array([[-1, 0.2, -1.0], [1, 0.2, -1.0], [1, 0.2, 5.0], [-1, 0.2, 5.0]])  # floor strip under the camera
    m2 = rasterize_mask(cam, np.eye(4), v2, np.array([[0, 1, 2], [0, 2, 3]]))
    assert m2[-1].any() and not m2[:100].any()


def test_exr_round_trip_full_frame(tmp_path):
    H, W = 24, 40
    rng = np.random.default_rng(0)
    passes = {"rgba": rng.random((H, W, 4), dtype=np.float32), "index": np.full((H, W), 3, np.float32),
              "depth": rng.random((H, W), dtype=np.float32) * 50, "shadow_catcher": np.ones((H, W, 3), np.float32),
              "diffuse_direct": rng.random((H, W, 3), dtype=np.float32)}
    write_passes(tmp_path / "a.exr", passes)
    back = read_passes(tmp_path / "a.exr")
    assert set(back) == set(passes)
    assert back["index"].dtype == np.int32 and (back["index"] == 3).all()
    for k in passes:
        assert np.allclose(back[k], passes[k]), k
    write_passes(tmp_path / "w.exr", passes, window=(5, 4, 20, 10))
    win = read_passes(tmp_path / "w.exr")
    assert win["rgba"].shape == (H, W, 4) and np.allclose(win["rgba"][4:10, 5:20], passes["rgba"][4:10, 5:20])
    assert win["rgba"][:4].max() == 0 and win["index"][:, :5].max() == 0 and win["shadow_catcher"][:4].min() == 1
    e = empty_passes(W, H, ["rgba", "shadow_catcher", "depth"])
    assert e["rgba"].max() == 0 and e["shadow_catcher"].min() == 1


def test_exr_bad_files_name_the_file(tmp_path):
    with pytest.raises(UserError, match="missing.exr"):
        read_passes(tmp_path / "missing.exr")
    bad = tmp_path / "bad.exr"
    bad.write_bytes(b"v/1\x01 not an exr at all")
    with pytest.raises(UserError, match="bad.exr"):
        read_passes(bad)


def test_exr_data_window_is_padded_to_the_display_window(tmp_path):
    import OpenEXR

    data = np.full((4, 5), 7.0, np.float32)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage,
              "dataWindow": (np.array([3, 2], np.int32), np.array([7, 5], np.int32)),
              "displayWindow": (np.array([0, 0], np.int32), np.array([15, 9], np.int32))}
    OpenEXR.File(header, {"ViewLayer.Object Index.X": data}).write(str(tmp_path / "w.exr"))
    idx = read_passes(tmp_path / "w.exr")["index"]
    assert idx.shape == (10, 16) and idx[2:6, 3:8].min() == 7 and idx.sum() == 7 * 20


def test_bad_plans_are_rejected_with_the_field_named():
    bad_T = FramePlan("f9", 0.0, np.full((4, 4), np.nan).tolist(), [car(1, 15, 0)], SUN)
    with pytest.raises(ValueError, match="T_world_cam"):
        fx.decide_effects(bad_T, CAM, Render(), {"rgba"})
    o = car(2, 15, 0)
    o.position = (15.0, float("nan"), 0.0)
    with pytest.raises(ValueError, match="object 2"):
        fx.decide_effects(plan_of(o), CAM, Render(), {"rgba"})
    with pytest.raises(ValueError, match="lighting.sun_strength"):
        fx.decide_effects(plan_of(car(3, 15, 0), lighting={**SUN, "sun_strength": float("inf")}), CAM,
                          Render(), {"rgba"})
    # Degenerate but valid: sun exactly overhead, object straddling the camera plane.
    overhead = {**SUN, "sun_direction": [0, 0, 1]}
    eff = fx.decide_effects(plan_of(car(4, 1.0, 0), lighting=overhead), CAM, Render(), {"rgba", "shadow_catcher"})
    assert eff.region.value is None or all(np.isfinite(eff.region.value))
    patches = fx.catcher_patches([car(4, 1.0, 0)], np.array([0.0, 0.0, 1.0]))
    assert len(patches) == 1 and np.all(np.isfinite(patches[0]))


def test_catcher_patches_never_overlap_on_one_ground():
    import cv2

    sun = fx.sun_direction(SUN)
    person = PlacedObject(2, "person", (15.2, 0.4, 0.0), 0.0, (0.6, 0.5, 1.7))
    (merged,) = fx.catcher_patches([car(1, 15, 0), person], sun)  # footprints overlap: one patch
    for obj in (car(1, 15, 0), person):
        for p in obj.box_corners_world()[:, :2]:
            assert cv2.pointPolygonTest(merged[:, :2].astype(np.float32), tuple(map(float, p)), False) > 0
    # A chain: each merge can make the hull reach the next one.
    chain = fx.catcher_patches([car(i, 15, 2.3 * i) for i in range(1, 5)] + [car(9, 40, -10)], sun)
    assert len(chain) == 2
    polys = [c[:, :2].astype(np.float32) for c in chain]
    assert cv2.intersectConvexConvex(polys[0], polys[1])[0] == 0
    # Apart, or one above the other (a rider on a raised platform): each keeps its own.
    assert len(fx.catcher_patches([car(1, 15, 0), car(2, 15, 6)], sun)) == 2
    raised = PlacedObject(3, "person", (15.0, 0.0, 0.5), 0.0, (0.6, 0.5, 1.7))
    assert sorted(round(p[0, 2], 2) for p in fx.catcher_patches([car(1, 15, 0), raised], sun)) == [0.0, 0.5]


def test_catcher_lift_small_but_above_float_precision():
    assert fx.catcher_lift_m(np.array([[10.0, 5.0, 0.0]])) == pytest.approx(2e-4)
    far = np.array([[30000.0, 100.0, 0.0]], np.float32)  # a twin far from its origin
    lift = fx.catcher_lift_m(far)
    assert lift > 2e-4 and np.float32(far[0, 0]) + np.float32(lift) > np.float32(far[0, 0])
    assert lift >= 8 * np.spacing(np.float32(30000.0))


def test_rider_shadow_is_caught_on_the_road_not_at_the_pegs():
    # A rider's box starts at the pegs (~0.2 m up): a catcher patch there cut the bike's
    # wheels out of the render (the patch hid everything below it) and lifted its shadow.
    from blendgen.scene.catalog import sample_variant
    from blendgen.scene.riders import split_rider

    rng = np.random.default_rng(3)
    v, d = next((v, d) for v, d in iter(lambda: sample_variant("motorcycle", rng), None) if "rider" in v)
    bike, rider = split_rider(PlacedObject(1, "motorcycle", (12.0, 0.0, 0.4), 0.0, d, v), 2)
    assert rider.position[2] > 0.4 + 0.1 and rider.variant["above_ground_m"] > 0.1
    assert fx.base_z(rider) == pytest.approx(0.4, abs=1e-3) and fx.base_z(bike) == pytest.approx(0.4)
    for patch in fx.catcher_patches([bike, rider], fx.sun_direction(SUN)):
        assert np.allclose(patch[:, 2], 0.4, atol=1e-3)
    _, shadow = fx.object_points(rider, fx.sun_direction(SUN))
    assert np.allclose(shadow[:, 2], 0.4, atol=1e-3)


def test_cluster_boxes_merge_neighbours_not_opposite_edges():
    # side by side: one region; opposite edges: one each; overlapping: one
    assert fx.cluster_boxes([(100, 100, 200, 200), (205, 100, 300, 200)], 20000) == [(100, 100, 300, 200)]
    far = [(0, 150, 100, 250), (540, 150, 640, 250)]
    assert fx.cluster_boxes(far, 20000) == far
    assert fx.cluster_boxes([(0, 0, 50, 50), (10, 10, 60, 60)], 0) == [(0, 0, 60, 60)]
    # two close ones merge, the far one stays alone
    got = fx.cluster_boxes([(0, 0, 60, 60), (70, 0, 130, 60), (500, 300, 560, 360)], 20000)
    assert got == [(0, 0, 130, 60), (500, 300, 560, 360)]
    # a very high per-render cost merges everything
    assert fx.cluster_boxes(far, 1e9) == [(0, 150, 640, 250)]


def test_region_clusters_objects_at_opposite_edges():
    left, right = car(1, 12, 6.5), car(2, 12, -6.5)
    eff = fx.decide_effects(plan_of(left, right), CAM, Render(), {"rgba", "index"})
    clusters = eff.regions
    assert len(clusters) == 2 and eff.region.value is not None
    union = eff.region.value
    assert sum((c[2] - c[0]) * (c[3] - c[1]) for c in clusters) < 0.6 * (union[2] - union[0]) * (union[3] - union[1])
    for o in (left, right):  # each object's projection lies inside one cluster
        uv, _ = CAM.project_world(T, o.box_corners_world())
        uv = np.clip(uv, 0, [CAM.width, CAM.height])  # the part in the frame
        assert any(c[0] <= uv[:, 0].min() and uv[:, 0].max() <= c[2] and c[1] <= uv[:, 1].min()
                   and uv[:, 1].max() <= c[3] for c in clusters)
    side = fx.decide_effects(plan_of(car(1, 12, 1.1), car(2, 12, -1.1)), CAM, Render(),
                             {"rgba", "index"})
    assert len(side.regions) == 1
    assert "clusters" in eff.to_dict()["region"]["extra"] and "extra" not in eff.to_dict()["passes"]


def test_a_gpu_merges_regions_that_a_cpu_keeps_apart():
    # a render call costs ~5 % of the frame on a GPU, 0.45 % on a CPU (docs/render.md)
    near = plan_of(car(1, 12, 3.0), car(2, 12, -3.0))
    cpu = fx.decide_effects(near, CAM, Render(), {"rgba", "index"})
    gpu = fx.decide_effects(near, CAM, Render(), {"rgba", "index"}, gpu=True)
    assert len(cpu.regions) == 2 and len(gpu.regions) == 1
    far = plan_of(car(1, 12, 6.5), car(2, 12, -6.5))  # opposite edges: two regions either way
    assert len(fx.decide_effects(far, CAM, Render(), {"rgba", "index"}, gpu=True).regions) == 2


def test_openexr_compresses_with_a_thread_pool(tmp_path):
    import os

    import OpenEXR

    write_passes(tmp_path / "a.exr", empty_passes(64, 32, ["rgba"]), window=(0, 0, 64, 32))
    assert OpenEXR.global_thread_count() == len(os.sched_getaffinity(0))


NIGHT = {**OVERCAST, "condition": "night", "lights_on": True,
         "street_light": {"direction": [0.3, 0.1, 0.94], "strength": 0.5, "color": [1.0, 0.8, 0.6], "angle_deg": 30.0}}


def test_street_lamps_stand_beside_each_object_at_night_only():
    """Night: one lamp on a pole near each object (ahead of or behind it, out to its side of
    the road), its power putting the street key's horizontal irradiance on the object's top;
    none by day. Lamps closer than LAMP_MERGE_M are one."""
    right, left, near_right = car(1, 20, -4), car(2, 30, 4), car(3, 22, -4.5)
    assert fx.street_lamps([right, left], T, SUN.get("street_light")) == []
    lamps = fx.street_lamps([right, left, near_right], T, NIGHT["street_light"])
    assert 1 <= len(lamps) <= 3 and lamps == fx.street_lamps([right, left, near_right], T, NIGHT["street_light"])
    by = {lp["object"]: lp for lp in lamps}
    assert by[1]["position"][1] < -4 - 0.9 and by[2]["position"][1] > 4 + 0.9  # out on each object's side
    for lp in lamps:
        assert lp["position"][2] == pytest.approx(fx.LAMP_HEIGHT_M) and lp["color"] == [1.0, 0.8, 0.6]
        o = {1: right, 2: left, 3: near_right}[lp["object"]]
        v = np.asarray(lp["position"]) - (np.asarray(o.position) + [0, 0, 1.0])
        E = lp["power_w"] / (4 * np.pi * (v @ v)) * v[2] / np.linalg.norm(v)
        assert E == pytest.approx(0.5 * 0.94 / np.linalg.norm([0.3, 0.1, 0.94]), rel=1e-6)
    positions = np.array([lp["position"] for lp in lamps])
    gaps = np.linalg.norm(positions[:, None, :2] - positions[None, :, :2], axis=2)
    assert (gaps[~np.eye(len(lamps), dtype=bool)] >= fx.LAMP_MERGE_M).all()


def test_ego_headlights_at_night_aim_ahead_low():
    assert fx.ego_headlights(T, None) == []
    beams = fx.ego_headlights(T, NIGHT["street_light"])
    assert len(beams) == 2
    ys = sorted(b["position"][1] for b in beams)
    assert ys == pytest.approx([-fx.HEADLIGHT_HALF_TRACK_M, fx.HEADLIGHT_HALF_TRACK_M])
    for b in beams:
        assert b["position"][0] == pytest.approx(fx.HEADLIGHT_AHEAD_M) and b["position"][2] == pytest.approx(0.7)
        d = np.asarray(b["direction"])
        assert d[0] > 0.99 and -0.05 < d[2] < 0  # along the heading, a little down
