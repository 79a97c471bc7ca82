"""User asset libraries (docs/assets.md): assets exported from Blender in the test itself
(benchmarks/realism/make_test_assets.py, run in its own process), imported in every format,
rendered by a job with `inject.assets:`; malformed assets each get a precise error, exit 2."""

from __future__ import annotations

import base64
import json
import struct
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from blendgen.cli import main
from blendgen.geometry import Camera
from blendgen.job.assets import AssetSampler, Sidecar, normalisation
from blendgen.job.schema import Inject
from blendgen.recording import folder
from blendgen.scene.ground_plane import GroundPlaneTwin
from blendgen.scene.planner import plan_sequence

ROOT = Path(__file__).resolve().parents[1]
CAM = Camera.from_hfov(320, 180, 70)
TRUE_DIMS = {"car": (4.42, 1.80, 1.45), "person": (0.30, 0.50, 1.75)}


# ----------------------------------------------------------------------------- fixtures

@pytest.fixture(scope="module")
def library(tmp_path_factory) -> Path:
    """Car and person exported from Blender as GLB, glTF, .blend, OBJ, FBX and USD."""
    out = tmp_path_factory.mktemp("library")
    r = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "realism" / "make_test_assets.py"), str(out)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    assert json.loads(r.stdout.strip().splitlines()[-1]) == {k: list(v) for k, v in TRUE_DIMS.items()}
    return out


def recording(root: Path, n: int = 3) -> Path:
    rec = root / "rec"
    (rec / "frames").mkdir(parents=True)
    folder.write_calib(rec, CAM)
    img = np.full((CAM.height, CAM.width, 3), 110, np.uint8)
    img[: CAM.height // 2] = (200, 170, 140)
    for i in range(n):
        cv2.imwrite(str(rec / "frames" / f"{i}.png"), img)
    folder.write_frames_csv(rec, [0.5 * i for i in range(n)], [f"frames/{i}.png" for i in range(n)])
    return rec


def write_job(root: Path, assets: list[str], **inject) -> Path:
    job = {"name": "assets", "seed": 1, "recording": str(recording(root)), "ground_plane": {"camera_height_m": 1.5},
           "inject": {"objects_per_frame": [3, 4], "classes": {"car": 2, "person": 1}, "distance_m": [6, 22],
                      "min_projected_px": 8, "assets": assets, **inject},
           "render": {"samples": 4, "denoise": False}, "post": {"illumination": "off"},
           "export": {"min_visible_px": 4, "formats": ["coco"]}, "output": "out"}
    p = root / "job.yaml"
    p.write_text(yaml.safe_dump(job))
    return p


# ----------------------------------------------------------------------------- normalisation (bpy-free)

def test_normalisation_scales_units_and_turns_axes():
    car = Sidecar(**{"class": "car"})
    # a car exported in centimetres, facing -y: read as centimetres, turned to x forward
    n = normalisation(car, np.array([-90.0, -221.0, 0.0]), np.array([90.0, 221.0, 145.0]), where="car")
    assert n["front"] == "-y" and n["front_inferred"]
    assert n["dims"] == pytest.approx([4.42, 1.80, 1.45]) and n["scale"] == pytest.approx(0.01)
    # no unit makes 100 a car's length: the nearest real length, proportions kept
    n100 = normalisation(car, np.zeros(3), np.array([18.0, 100.0, 14.0]), where="car")
    assert n100["dims"] == pytest.approx([5.6, 1.008, 0.784])
    T = np.array(n["transform"])
    front = T[:3, :3] @ np.array([0, -221.0, 72.5]) + T[:3, 3]  # middle of the front face
    assert front[0] == pytest.approx(n["dims"][0] / 2) and abs(front[1]) < 1e-9
    bottom = T[:3, :3] @ np.array([0, 0, 0.0]) + T[:3, 3]
    assert bottom[2] == pytest.approx(0.0)  # stands on the ground
    # stated dims win; a person stated 1.80 m tall
    p = normalisation(Sidecar(**{"class": "person", "height_m": 1.8}), np.zeros(3), np.array([0.5, 0.3, 1.0]), "p")
    assert p["dims"][2] == pytest.approx(1.8) and p["front"] == "-y"


def test_planner_mixes_library_assets_by_share():
    gp = GroundPlaneTwin(1.5, 0.0, 3.5)
    poses = [(f"{i:06d}", i / 5.0, gp.camera_pose()) for i in range(20)]
    entry = {"key": "lib/van.glb", "file": "/lib/van.glb", "format": "gltf", "variant": None, "cls": "car",
             "transform": np.eye(4).tolist(), "fingerprint": "f", "dims": [5.0, 2.0, 1.9]}
    inj = Inject(classes={"car": 1, "person": 1}, objects_per_frame=(4, 6))
    base = plan_sequence(gp, CAM, poses, inj, 3)
    assert plan_sequence(gp, CAM, poses, inj, 3, assets=AssetSampler([entry], 0.0)) == base
    objs = {o.id: o for p in plan_sequence(gp, CAM, poses, inj, 3, assets=AssetSampler([entry], 1.0)) for o in p.objects}
    cars = [o for o in objs.values() if o.cls == "car"]
    assert cars and all(o.variant["asset"] == "lib/van.glb" and o.dims == (5.0, 2.0, 1.9) for o in cars)
    assert all("asset" not in o.variant for o in objs.values() if o.cls == "person")  # no person asset
    # library draws have their own stream: the first object stands where the procedural one did
    first = lambda plans: min((o for o in plans[0].objects), key=lambda o: o.id)  # noqa: E731
    lib_plans = plan_sequence(gp, CAM, poses, inj, 3, assets=AssetSampler([entry], 1.0))
    assert first(lib_plans).position == first(base).position and first(lib_plans).cls == first(base).cls
    half = [o for p in plan_sequence(gp, CAM, poses, inj, 3, assets=AssetSampler([entry], 0.5)) for o in p.objects]
    # per class: cars from the library, persons (none in the library) procedural, buses never
    per = [o for p in plan_sequence(gp, CAM, poses, inj, 3, assets=AssetSampler([entry], {"car": 1.0, "bus": 0.0}))
           for o in p.objects]
    assert all("asset" in o.variant for o in per if o.cls == "car")
    assert plan_sequence(gp, CAM, poses, inj, 3, assets=AssetSampler([entry], {"car": 0.0})) == base
    with pytest.raises(Exception, match="unknown class 'lorry'"):
        Inject(asset_share={"lorry": 1.0})
    lib = {o.id for o in half if "asset" in o.variant}
    proc = {o.id for o in half if o.cls == "car" and "asset" not in o.variant}
    assert lib and proc


# ----------------------------------------------------------------------------- malformed assets

def _gltf(**over) -> str:
    """A small valid glTF 2 document: one triangle, its buffer inline."""
    pts = struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 1, 0)
    doc = {"asset": {"version": "2.0"}, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
           "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
           "buffers": [{"byteLength": 36, "uri": "data:application/octet-stream;base64," + base64.b64encode(pts).decode()}],
           "bufferViews": [{"buffer": 0, "byteLength": 36}],
           "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                          "min": [0, 0, 0], "max": [1, 1, 0]}]}
    doc.update(over)
    return json.dumps(doc)


def _glb(length_delta=0) -> bytes:
    js = _gltf().encode()
    js += b" " * (-len(js) % 4)
    body = struct.pack("<II", len(js), 0x4E4F534A) + js
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body) + length_delta) + body


CAR = "class: car\n"
OBJ_TRI = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
# name -> (files of the asset folder, text the error must contain)
MALFORMED = {
    "no sidecar": ({"car.gltf": _gltf()}, "no sidecar: write car.yaml"),
    "unknown class": ({"car.gltf": _gltf(), "car.yaml": "class: spaceship\n"}, "unknown class 'spaceship'"),
    "sidecar not a mapping": ({"car.gltf": _gltf(), "car.yaml": "- car\n"}, "expected a mapping of sidecar fields"),
    "sidecar bad YAML": ({"car.gltf": _gltf(), "car.yaml": "class: [car\n"}, "not valid YAML"),
    "sidecar unknown key": ({"car.gltf": _gltf(), "car.yaml": CAR + "colour: red\n"}, "colour: unknown key"),
    "bad axis": ({"car.gltf": _gltf(), "car.yaml": CAR + "front: forward\n"}, "front: expected an axis"),
    "front is up": ({"car.gltf": _gltf(), "car.yaml": CAR + "front: +z\n"}, "front +z and up +z are the same axis"),
    "absurd stated size": ({"car.gltf": _gltf(), "car.yaml": CAR + "dims: [400, 1.8, 1.5]\n"},
                           "absurd size: length 400 m for a car"),
    "negative height": ({"car.gltf": _gltf(), "car.yaml": CAR + "height_m: -1\n"}, "height_m: Input should be greater than 0"),
    "two sizes": ({"car.gltf": _gltf(), "car.yaml": CAR + "height_m: 1.5\nlength_m: 4\n"}, "give one of dims, height_m, length_m or unit_m"),
    "folder sidecar bad": ({"car.gltf": _gltf(), "asset.yaml": "class: car\nvariants: 3\n"}, "variants: Input should be a valid list"),
    "glTF not JSON": ({"car.gltf": "{not json", "car.yaml": CAR}, "glTF JSON does not parse"),
    "glTF 1": ({"car.gltf": _gltf(asset={"version": "1.0"}), "car.yaml": CAR}, "not a glTF 2 document"),
    "glTF no meshes": ({"car.gltf": _gltf(meshes=[]), "car.yaml": CAR}, "no geometry: the glTF has no meshes"),
    "glTF missing buffer": ({"car.gltf": _gltf(buffers=[{"byteLength": 36, "uri": "car.bin"}]), "car.yaml": CAR},
                            "missing buffer file 'car.bin'"),
    "glTF missing texture": ({"car.gltf": _gltf(images=[{"uri": "paint.png"}]), "car.yaml": CAR},
                             "missing texture file 'paint.png'"),
    "GLB bad magic": ({"car.glb": b"PK\x03\x04" + bytes(40), "car.yaml": CAR}, "not a GLB file"),
    "GLB truncated": ({"car.glb": _glb(length_delta=100), "car.yaml": CAR}, "GLB file truncated or padded"),
    "empty file": ({"car.glb": b"", "car.yaml": CAR}, "the asset file is empty"),
    "OBJ no faces": ({"car.obj": "v 0 0 0\nv 1 0 0\n", "car.yaml": CAR}, "no geometry: the OBJ has no vertices"),
    "OBJ missing mtl": ({"car.obj": "mtllib car.mtl\n" + OBJ_TRI, "car.yaml": CAR}, "missing material library 'car.mtl'"),
    "OBJ missing texture": ({"car.obj": "mtllib car.mtl\n" + OBJ_TRI, "car.mtl": "newmtl a\nmap_Kd -bm 1 paint.jpg\n",
                             "car.yaml": CAR}, "missing texture 'paint.jpg' (named in car.mtl;"),
    "FBX bad header": ({"car.fbx": b"\x00" * 64, "car.yaml": CAR}, "not an FBX file"),
    "FBX ASCII": ({"car.fbx": "; FBX 7.4.0 project file\nFBXHeaderExtension:  {\n}\n", "car.yaml": CAR},
                  "ASCII FBX: Blender's importer reads binary FBX only"),
    "USD bad header": ({"car.usda": "hello\n", "car.yaml": CAR}, "not a .usda file"),
    "blend bad header": ({"car.blend": b"NOTBLEND" + bytes(40), "car.yaml": CAR}, "not a .blend file"),
    "empty folder": ({"readme.txt": "nothing here"}, "no assets in this folder"),
}


@pytest.mark.parametrize("name", list(MALFORMED))
def test_malformed_asset_precise_error_exit_2(name, tmp_path, capsys):
    files, expected = MALFORMED[name]
    lib = tmp_path / "lib"
    lib.mkdir()
    for fn, content in files.items():
        (lib / fn).write_bytes(content.encode() if isinstance(content, str) else content)
    job = write_job(tmp_path, ["lib"])
    assert main(["validate", str(job)]) == 2
    err = capsys.readouterr().err
    assert expected in err, err
    assert "Traceback" not in err
    named = [fn for fn in files if fn.endswith((".gltf", ".glb", ".obj", ".fbx", ".usda", ".blend", ".yaml"))]
    assert any(str(lib / fn) in err for fn in named) or (name == "empty folder" and str(lib) in err), err


def test_bad_asset_paths(tmp_path, capsys):
    (tmp_path / "car.3ds").write_bytes(b"x")
    for i, (path, expected) in enumerate((("nowhere", "asset path does not exist"),
                                          (str(tmp_path / "car.3ds"), "unsupported asset format '.3ds'"))):
        assert main(["validate", str(write_job(tmp_path / str(i), [path]))]) == 2
        err = capsys.readouterr().err
        assert expected in err and "Traceback" not in err, err


# ----------------------------------------------------------------------------- with Blender

@pytest.mark.bpy
def test_every_format_imports_with_its_real_dims(library):
    import bpy  # noqa: F401  (this test measures in-process)

    from blendgen.job.assets import asset_variant, discover
    from blendgen.render.assets import AssetLibrary, inspect

    refs = discover([library])
    assert {r.format for r in refs} == {"gltf", "blend", "obj", "fbx", "usd"}
    lib = AssetLibrary()
    for ref in refs:
        e = inspect(ref)
        cls = "car" if "car" in Path(ref.file).stem else "person"
        assert e["cls"] == cls and e["dims"] == pytest.approx(TRUE_DIMS[cls], abs=0.01), ref.key
        assert e["front"] == "-y"
        if ref.variant != "car_blue":
            continue
        # the baked template: bottom centre at the origin, exactly the catalog's box
        lib.load(asset_variant(e))
        v = np.concatenate([_verts(me, M) for me, M in lib.templates[(ref.file, "car_blue")]])
        assert v.min(axis=0) == pytest.approx([-2.21, -0.9, 0.0], abs=1e-4)
        assert v.max(axis=0) == pytest.approx([2.21, 0.9, 1.45], abs=1e-4)


@pytest.mark.bpy
def test_procedural_objects_exported_as_glb_keep_their_dims(tmp_path):
    """Every class round-trips through glTF (the library make_test_assets --procedural
    writes for benchmarks): the catalog measures what the procedural builder made."""
    r = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "realism" / "make_test_assets.py"), str(tmp_path),
                        "--procedural", "1"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    made = json.loads(r.stdout.strip().splitlines()[-1])
    import bpy  # noqa: F401

    from blendgen.job.assets import discover
    from blendgen.render.assets import inspect

    entries = {Path(ref.file).name: inspect(ref) for ref in discover([tmp_path])}
    assert set(entries) == set(made) and len(made) == 7
    for name, dims in made.items():
        assert entries[name]["dims"] == pytest.approx(dims, abs=1e-3), name
        assert entries[name]["scale"] == pytest.approx(1.0)


def _verts(me, M) -> np.ndarray:
    co = np.empty(len(me.vertices) * 3)
    me.vertices.foreach_get("co", co)
    M = np.array(M)
    return co.reshape(-1, 3) @ M[:3, :3].T + M[:3, 3]


def _tris(me) -> np.ndarray:
    me.calc_loop_triangles()
    t = np.empty(len(me.loop_triangles) * 3, np.int64)
    me.loop_triangles.foreach_get("vertices", t)
    return t.reshape(-1, 3)


@pytest.mark.bpy
def test_job_renders_gltf_and_blend_assets_with_exact_masks_and_boxes(library, tmp_path):
    import bpy  # noqa: F401

    from blendgen.plan import FramePlan
    from blendgen.render.assets import AssetLibrary
    from blendgen.render.raster import rasterize_mask

    job = write_job(tmp_path, [str(library / "gltf"), str(library / "blend")])
    r = subprocess.run([sys.executable, "-m", "blendgen.cli", "run", str(job), "--quiet"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-3000:]
    out = tmp_path / "out"
    catalog = json.loads((out / "assets.json").read_text())["assets"]
    assert len(catalog) == 6  # car.gltf, person.gltf, car.blend x 3 variants, person.blend
    for e in catalog:
        assert e["dims"] == pytest.approx(TRUE_DIMS[e["cls"]], abs=0.01), e["key"]

    plans = [FramePlan.from_dict(json.loads(line)) for line in (out / "plan.jsonl").read_text().splitlines()]
    objs = [o for p in plans for o in p.objects]
    assert objs and all("asset" in o.variant for o in objs)  # asset_share 1: every car and person
    lib = AssetLibrary()
    checked = 0
    for p in plans:
        labels = {i["id"]: i for i in json.loads((out / "frames" / p.frame_id / "labels.json").read_text())["instances"]}
        index = cv2.imread(str(out / "frames" / p.frame_id / "instances.png"), cv2.IMREAD_UNCHANGED)
        projected = {}
        for o in p.objects:
            lib.load(o.variant)
            c, s = np.cos(o.yaw), np.sin(o.yaw)
            R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
            vs, ts, n = [], [], 0
            for me, M in lib.templates[(o.variant["file"], o.variant.get("node"))]:
                v = _verts(me, M)
                vs.append(v @ R.T + np.asarray(o.position))
                ts.append(_tris(me) + n)
                n += len(v)
            projected[o.id] = rasterize_mask(CAM, p.T_world_cam, np.concatenate(vs), np.concatenate(ts)) > 0
        for o in p.objects:
            if o.id not in labels:
                continue
            lab = labels[o.id]
            L, W, H = catalog_dims = next(e["dims"] for e in catalog if e["key"] == o.variant["asset"])
            assert lab["box3d_cam"]["dimensions_hwl"] == pytest.approx([H, W, L], abs=1e-6)
            assert tuple(o.dims) == pytest.approx(catalog_dims)
            others = np.any([m for i, m in projected.items() if i != o.id], axis=0) if len(projected) > 1 else 0
            if np.any(projected[o.id] & others):
                continue  # occluded or occluding: the index pass differs from the amodal mask
            rendered = index == o.id
            iou = np.count_nonzero(rendered & projected[o.id]) / np.count_nonzero(rendered | projected[o.id])
            assert iou > 0.9, (p.frame_id, o.id, o.cls, iou)
            checked += 1
    assert checked >= 3


@pytest.mark.bpy
def test_bad_assets_found_in_blender_stop_the_run_before_rendering(library, tmp_path):
    lib = tmp_path / "lib"
    lib.mkdir()
    script = f"""
import bpy
bpy.ops.wm.read_factory_settings(use_empty=True)
cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
bpy.context.scene.collection.objects.link(cam)
bpy.ops.wm.save_as_mainfile(filepath={str(lib / 'nogeo.blend')!r})
bpy.ops.mesh.primitive_cube_add(size=1.8)
m = bpy.data.materials.new("paint"); m.use_nodes = True
tex = m.node_tree.nodes.new("ShaderNodeTexImage")
tex.image = bpy.data.images.load({str(tmp_path / 'gone.png')!r}, check_existing=False)
bpy.context.active_object.data.materials.append(m)
bpy.ops.wm.save_as_mainfile(filepath={str(lib / 'notex.blend')!r})
"""
    cv2.imwrite(str(tmp_path / "gone.png"), np.zeros((4, 4, 3), np.uint8))
    r = subprocess.run([sys.executable, "-W", "ignore", "-c", script], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    (tmp_path / "gone.png").unlink()  # the .blend names a texture that is not there
    (lib / "nogeo.yaml").write_text(CAR)
    (lib / "notex.yaml").write_text("class: car\nheight_m: 1.5\n")
    (lib / "wrongvariant.blend").write_bytes((library / "blend" / "car.blend").read_bytes())
    (lib / "wrongvariant.yaml").write_text("class: car\nvariants: [car_green]\n")
    (lib / "carperson.glb").write_bytes((library / "glb" / "car.glb").read_bytes())
    (lib / "carperson.yaml").write_text("class: person\n")  # a car's shape called a person
    (lib / "corrupt.fbx").write_bytes(b"Kaydara FBX Binary  \x00\x1a\x00" + b"garbage" * 4)  # header only
    (lib / "corrupt.yaml").write_text(CAR)
    job = write_job(tmp_path, ["lib"])
    r = subprocess.run([sys.executable, "-m", "blendgen.cli", "run", str(job), "--quiet"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 2, r.stderr[-3000:]
    err = r.stderr
    assert "5 bad library asset(s); nothing was rendered" in err and "Traceback" not in err, err
    for expected in (f"{lib / 'nogeo.blend'}: no geometry", f"{lib / 'notex.blend'}: missing texture",
                     f"{lib / 'wrongvariant.blend'}#car_green: variant 'car_green' is neither",
                     f"{lib / 'carperson.glb'}: absurd size", f"{lib / 'corrupt.fbx'}: Blender's fbx importer failed"):
        assert expected in err, (expected, err)
    assert not (tmp_path / "out" / "frames").exists() and not (tmp_path / "out" / "plan.jsonl").exists()


# ----------------------------------------------------------------------------- assets as they come (issue 44)

THIRDPARTY = ROOT.parent / "shared" / "data" / "assets_thirdparty"


def _gazebo_model(root: Path, name: str, scale: str = "0.01 0.01 0.01", texture: str = "model://other/t/wheel.png"):
    """A Gazebo model folder: model.sdf naming meshes/<name>.obj at `scale`, the OBJ's .mtl naming
    a texture of another model by a model:// URI."""
    m = root / name
    (m / "meshes").mkdir(parents=True)
    (m / "model.sdf").write_text(f"<sdf version='1.6'><model name='{name}'><link name='l'><visual name='v'>"
                                 f"<geometry><mesh><scale>{scale}</scale><uri>model://{name}/meshes/{name}.obj</uri>"
                                 "</mesh></geometry></visual></link></model></sdf>")
    (m / "meshes" / f"{name}.obj").write_text(f"mtllib {name}.mtl\nusemtl a\n" + OBJ_TRI)
    (m / "meshes" / f"{name}.mtl").write_text(f"newmtl a\nmap_Kd {texture}\n")
    (root / "other" / "t").mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(root / "other" / "t" / "wheel.png"), np.zeros((4, 4, 3), np.uint8))
    (root / "LICENSE").write_text("Creative Commons Attribution 3.0\n")
    return m


def test_gazebo_model_gives_unit_up_licence_and_textures_by_model_uri(tmp_path, capsys):
    from blendgen.job.assets import discover

    m = _gazebo_model(tmp_path / "models", "bus")
    # no sidecar: the class comes from the job's entry, the rest from model.sdf and LICENSE
    refs = discover([(m, {"class": "bus"})])
    sc = refs[0].sidecar
    assert sc["class"] == "bus" and sc["unit_m"] == 0.01 and sc["up"] == "-y"
    assert sc["licence"].startswith("Creative Commons Attribution 3.0")
    assert any("model.sdf" in n for n in refs[0].notes)
    # the same through a job: `inject.assets: [{path: ..., class: ...}]`
    job = write_job(tmp_path, [{"path": str(m), "class": "bus"}], classes={"bus": 1})
    assert main(["validate", str(job)]) == 0, capsys.readouterr().err
    # a model:// texture that is nowhere: a precise error that says how to go on
    m2 = _gazebo_model(tmp_path / "m2", "van", texture="model://gone/t/x.png")
    with pytest.raises(Exception, match=r"missing texture 'model://gone/t/x.png' \(named in van.mtl.*missing_textures: ignore"):
        discover([(m2, {"class": "car"})])
    assert discover([(m2, {"class": "car", "missing_textures": "ignore"})])


def test_openmaterial_xoma_gives_class_licence_and_iso_axes(tmp_path):
    from blendgen.job.assets import discover

    (tmp_path / "walker.gltf").write_text(_gltf())
    (tmp_path / "walker.xoma").write_text(json.dumps({"metadata": {"objectClass": "human", "license": "MPL-2.0"}}))
    (tmp_path / "roadster.gltf").write_text(_gltf())
    (tmp_path / "roadster.xoma").write_text(json.dumps({"metadata": {
        "objectClass": "vehicle", "license": "MPL-2.0", "vehicleClassData": {"vehicleCategory": "car"}}}))
    got = {Path(r.file).stem: r.sidecar for r in discover([tmp_path])}
    assert got["walker"]["class"] == "person" and got["roadster"]["class"] == "car"
    assert all(s["front"] == "+x" and s["up"] == "+z" and s["licence"] == "MPL-2.0" for s in got.values())
    # a sidecar beside the file overrides the metadata key by key
    (tmp_path / "roadster.yaml").write_text("class: truck\nlicense: CC0\n")
    got = {Path(r.file).stem: r.sidecar for r in discover([tmp_path])}
    assert got["roadster"]["class"] == "truck" and got["roadster"]["licence"] == "CC0"


def test_absurd_size_names_the_axes_and_unit_that_fit():
    from blendgen.errors import UserError

    # a Gazebo bus read as Y-up (Blender's OBJ default): height along -y, length along z, in cm
    lo, hi = np.array([-135.4, -369.8, -629.5]), np.array([135.4, 0.1, 619.1])
    with pytest.raises(UserError, match=r"absurd size.*With up along y .*front along z and `unit_m: 0.01` \(cm\) "
                                        r"it is 12.49 x 2.71 x 3.70 m"):
        normalisation(Sidecar(**{"class": "bus"}), lo, hi, where="bus.obj")
    n = normalisation(Sidecar(**{"class": "bus", "up": "-y", "unit_m": 0.01}), lo, hi, where="bus.obj")
    assert n["dims"] == pytest.approx([12.486, 2.708, 3.699], abs=1e-3)
    # the front found from the geometry is used when the sidecar does not state one
    n = normalisation(Sidecar(**{"class": "bus", "up": "-y", "unit_m": 0.01}), lo, hi, where="bus.obj",
                      front="-z", front_source="tail lamps")
    assert n["front"] == "-z" and n["front_source"] == "tail lamps" and n["front_inferred"]


@pytest.mark.bpy
def test_obj_parts_without_material_get_a_neutral_one(tmp_path):
    import bpy  # noqa: F401

    from blendgen.job.assets import discover
    from blendgen.render.assets import DEFAULT_MATERIAL, _Import

    # a box of 4.4 x 1.8 x 1.5 m exported without any material (no mtllib, no usemtl)
    v = [(x, y, z) for x in (-2.2, 2.2) for y in (-0.9, 0.9) for z in (0, 1.5)]
    faces = [(1, 2, 4, 3), (5, 6, 8, 7), (1, 2, 6, 5), (3, 4, 8, 7), (1, 3, 7, 5), (2, 4, 8, 6)]
    text = "".join(f"v {x} {z} {-y}\n" for x, y, z in v) + "".join(f"f {a} {b} {c} {d}\n" for a, b, c, d in faces)
    (tmp_path / "car.obj").write_text(text)
    (tmp_path / "car.yaml").write_text("class: car\n")
    from blendgen.render.assets import inspect

    ref = discover([tmp_path])[0]
    e = inspect(ref)
    assert e["dims"] == pytest.approx([4.4, 1.8, 1.5], abs=1e-3) and e["parts_without_material"]
    with _Import(ref) as imp:
        mats = {m.name if m else None for me, _ in imp.parts() for m in me.materials}
    assert DEFAULT_MATERIAL in mats and None not in mats


def _need_thirdparty():
    if not (THIRDPARTY / "gazebo_models" / "bus" / "model.sdf").is_file():
        pytest.skip("needs ../shared/data/assets_thirdparty (gazebo_models, openmaterial3d, openmaterial_validation)")


THIRDPARTY_JOB = [("openmaterial3d", {}),
                  ("openmaterial_validation", {"class": "truck", "missing_textures": "ignore"}),
                  ("gazebo_models/prius_hybrid", {"class": "car"}), ("gazebo_models/suv", {"class": "car"}),
                  ("gazebo_models/hatchback", {"class": "car"}), ("gazebo_models/bus", {"class": "bus"}),
                  ("gazebo_models/stop_light", {"class": "traffic light", "front": "-x"})]


@pytest.mark.bpy
def test_thirdparty_assets_as_they_come_get_real_sizes_and_fronts():
    """The shared third-party models as downloaded: glTF with a rigged man whose importer adds
    a 2 m bone-shape icosphere, a truck whose plate texture is missing, Gazebo OBJs in cm and
    inches, Z-up, with textures of other models (model://). Sizes within a few cm of the real
    vehicles', fronts from the tail lamps (checked by eye on renders from the front and back)."""
    _need_thirdparty()
    import bpy

    from blendgen.job.assets import discover
    from blendgen.render.assets import inspect

    got = {}
    for ref in discover([(THIRDPARTY / p, f) for p, f in THIRDPARTY_JOB]):
        bpy.ops.wm.read_factory_settings(use_empty=True)
        got[Path(ref.file).stem] = inspect(ref)
    man = got["human_example"]
    assert man["cls"] == "person" and man["hidden_parts_skipped"] == ["Icosphere"] and man["rigged_parts_posed"]
    assert 1.7 < man["dims"][2] < 1.85 and man["dims"][1] < 0.7  # the icosphere would make it 2 m wide
    assert got["vehicle_example"]["dims"] == pytest.approx([3.855, 1.618, 1.296], abs=0.01)
    truck = got["truck_example"]
    assert truck["front"] == "-x" and truck["front_source"].startswith("tail lamps")
    assert truck["textures_missing_ignored"] == ["Number_Plate"]
    expect = {"Hybrid": ("-z", [4.62, 2.01, 1.54]), "hatchback": ("-z", [4.0, 2.14, 1.57]),
              "suv": ("+z", [5.02, 2.60, 2.16]), "bus": ("-z", [12.49, 2.71, 3.70])}
    for stem, (front, dims) in expect.items():
        assert got[stem]["front"] == front and got[stem]["front_source"].startswith("tail lamps"), stem
        assert got[stem]["dims"] == pytest.approx(dims, abs=0.01), stem
    assert got["bus"]["textures_relinked"] == ["wheels_01.png"]  # model://suv/materials/textures/wheels_01.png
    assert got["stop_light"]["front"] == "-x" and got["stop_light"]["dims"][2] == pytest.approx(0.762, abs=0.01)
