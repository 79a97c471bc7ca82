"""User asset libraries, the Blender half (docs/assets.md): import with Blender's own
importers, measure, and build placed instances from a per-session cache.

Imports bpy: only farm workers may import this module. `AssetInspector` is the farm
processor of the `assets` step (one import per asset, results to
OUT/.blendgen/assets/<fingerprint>.json); `AssetLibrary` lives in the warm RenderSession and
imports each file once, keeping the asset as a template of (mesh, matrix) pairs from which
every placed instance is made of linked duplicates (shared meshes and materials).
"""

from __future__ import annotations

from pathlib import Path

import bpy
import cv2
import numpy as np
from mathutils import Matrix

from blendgen import atomic
from blendgen.errors import UserError
from blendgen.job.assets import AssetRef, normalisation, resolve_reference, result_path
from blendgen.plan import PlacedObject

MESHLIKE = {"MESH", "CURVE", "SURFACE", "META", "FONT"}
LIB_PREFIX = "blendgen_asset"
DEFAULT_MATERIAL = f"{LIB_PREFIX}_no_material"  # parts the file gives no material: a neutral grey
VEHICLES = ("car", "truck", "bus", "motorcycle", "bicycle")


def _import_file(path: Path, fmt: str) -> None:
    """Blender's own importer for the format; adds the file's objects to the active collection."""
    p = str(path)
    if fmt == "gltf":
        bpy.ops.import_scene.gltf(filepath=p)
    elif fmt == "obj":
        bpy.ops.wm.obj_import(filepath=p)
    elif fmt == "fbx":
        bpy.ops.import_scene.fbx(filepath=p)
    elif fmt == "usd":
        bpy.ops.wm.usd_import(filepath=p)
    else:
        raise ValueError(fmt)


def _append_blend(path: Path, variant: str | None, coll) -> None:
    """Append the .blend's collection (or object) named `variant`; without a variant every
    object of the file."""
    with bpy.data.libraries.load(str(path), link=False) as (src, dst):
        have_c, have_o = list(src.collections), list(src.objects)
        if variant is None:
            dst.objects = have_o
        elif variant in have_c:
            dst.collections = [variant]
        elif variant in have_o:
            dst.objects = [variant]
        else:
            raise UserError(f"variant {variant!r} is neither a collection nor an object of the file "
                            f"(collections: {have_c[:20]}, objects: {have_o[:20]})", where=str(path))
    for c in dst.collections:
        if c is not None:
            coll.children.link(c)
    for o in dst.objects:
        if o is not None:
            coll.objects.link(o)


class _Import:
    """A file's objects in a temporary collection of the scene, removed on exit; `parts()`
    bakes what the asset (its variant) draws (modifiers, collection/geometry-node instances and linked
    duplicates included) into (mesh, 4x4 world matrix) pairs."""

    def __init__(self, ref: AssetRef):
        self.ref = ref

    def __enter__(self):
        scene = bpy.context.scene
        self.coll = bpy.data.collections.new(f"{LIB_PREFIX}_import")
        scene.collection.children.link(self.coll)
        lc = bpy.context.view_layer.layer_collection.children[self.coll.name]
        bpy.context.view_layer.active_layer_collection = lc
        before, images = set(bpy.data.objects), set(bpy.data.images)
        path = Path(self.ref.file)
        try:
            if self.ref.format == "blend":
                _append_blend(path, self.ref.variant, self.coll)
            else:
                _import_file(path, self.ref.format)
        except Exception as e:
            self.__exit__()
            if isinstance(e, UserError):
                raise
            # the importer's own words: it knows what is wrong with the file
            raise UserError(f"Blender's {self.ref.format} importer failed: {str(e).strip()[:400]}",
                            where=str(path)) from None
        finally:
            bpy.context.view_layer.active_layer_collection = bpy.context.view_layer.layer_collection
        new = [o for o in bpy.data.objects if o not in before]
        # Objects in no collection are the importer's helpers, not the asset's: the glTF
        # importer's bone shape (a 2 m icosphere per rigged file) is one. Importers may put the
        # asset's own objects in the scene collection instead of the active one.
        self.objects = [o for o in new if o.users_collection]
        self.helpers = [o for o in new if not o.users_collection]
        self.images = [im for im in bpy.data.images if im not in images]
        for o in self.objects:
            if self.coll not in o.users_collection:
                self.coll.objects.link(o)
        self.relinked, self.dropped = _fix_textures(self.images, path.parent)
        bpy.context.view_layer.update()
        return self

    def hidden(self) -> list[str]:
        """The file's objects that are not part of what it draws: hidden from renders, custom
        bone shapes, and the importer's helpers."""
        shapes = {pb.custom_shape.name for o in self.objects if o.type == "ARMATURE" and o.pose
                  for pb in o.pose.bones if pb.custom_shape is not None}
        return sorted({o.name for o in self.objects if o.type in MESHLIKE and (o.hide_render or o.name in shapes)}
                      | {o.name for o in self.helpers if o.type in MESHLIKE})

    def roots(self) -> set[str] | None:
        """Names of the objects the asset's variant draws (None: all)."""
        variant = self.ref.variant
        if variant is None:
            return None
        if self.ref.format == "blend":
            # a second import of the same file renames its collections (car_red.001)
            c = next((x for x in self.coll.children_recursive
                      if x.name == variant or x.name.rsplit(".", 1)[0] == variant), None)
            if c is not None:
                return {o.name for o in c.all_objects}
        ob = next((o for o in self.objects if o.name == variant or o.name.split(".")[0] == variant), None)
        if ob is None:
            names = sorted(o.name for o in self.objects)[:20]
            raise UserError(f"variant {variant!r} is not an object of the file (objects: {names})",
                            where=self.ref.file)
        return {ob.name, *(c.name for c in ob.children_recursive)}

    def parts(self) -> list[tuple[object, np.ndarray]]:
        keep = self.roots()
        skip = set(self.hidden())
        dg = bpy.context.evaluated_depsgraph_get()
        baked: dict[tuple[str, str], object] = {}
        names = {o.name for o in self.objects}
        out = []
        self.no_material, self.rigged = [], []
        for inst in dg.object_instances:
            ob = inst.object
            if ob.type not in MESHLIKE:
                continue
            # What draws it: the object itself, or the instancer (collection instance, geometry nodes)
            owner = (inst.parent if inst.is_instance else ob).original
            if owner.name not in names or (keep is not None and owner.name not in keep) or \
                    ob.original.name in skip:
                continue
            # One baked mesh per source object and its evaluated data: every instance of it shares it.
            key = (ob.original.name, ob.data.name if ob.data is not None else "")
            if key not in baked:
                # a rigged mesh is baked in the pose its armature holds at the scene's frame
                if any(m.type == "ARMATURE" for m in getattr(ob.original, "modifiers", [])):
                    self.rigged.append(ob.original.name)
                me = bpy.data.meshes.new_from_object(ob, preserve_all_data_layers=True, depsgraph=dg)
                me.name = f"{LIB_PREFIX}_{Path(self.ref.file).stem}_{key[0]}"
                if _fill_materials(me):
                    self.no_material.append(ob.original.name)
                baked[key] = me
            if len(baked[key].polygons):
                out.append((baked[key], np.array(inst.matrix_world)))
        return out

    def textures(self) -> list[dict]:
        """Images the import brought in; external ones that do not exist are missing."""
        out = []
        for im in self.images:
            if im.source != "FILE" or im.packed_file is not None:
                continue
            path = Path(bpy.path.abspath(im.filepath, library=im.library)) if im.filepath else None
            out.append({"name": im.name, "file": str(path) if path else None,
                        "missing": bool(path is None or not path.is_file()) and not im.has_data})
        return out

    def __exit__(self, *exc):
        for o in list(self.coll.all_objects) + list(getattr(self, "helpers", [])):
            bpy.data.objects.remove(o, do_unlink=True)
        for c in list(self.coll.children_recursive):
            bpy.data.collections.remove(c)
        bpy.data.collections.remove(self.coll)
        return False


def _fix_textures(images, folder: Path) -> tuple[list[str], list[str]]:
    """Images the import could not load: found again where `resolve_reference` looks (a
    Gazebo `model://` URI, a sibling textures folder, another case) and put in their place in
    ``images`` (in place), else taken out of their materials, which then render with their base
    colour (Cycles draws a missing image magenta). Returns (relinked, dropped) image names."""
    relinked, dropped = [], []
    for im in list(images):
        if im.source != "FILE" or im.packed_file is not None:
            continue
        raw = im.filepath_raw or im.filepath or im.name
        if "model://" not in raw and Path(bpy.path.abspath(raw, library=im.library)).is_file():
            continue
        ref = raw[raw.index("model://"):] if "model://" in raw else raw
        found = resolve_reference(ref, folder) or resolve_reference(Path(ref).name, folder)
        if found is not None:
            # a fresh image of the found file (an image that failed to load does not reload)
            new = bpy.data.images.load(str(found), check_existing=True)
            im.user_remap(new)
            relinked.append(im.name)
            images[images.index(im)] = new
            bpy.data.images.remove(im)
            continue
        for mat in bpy.data.materials:
            if mat.node_tree is None:
                continue
            for node in [n for n in mat.node_tree.nodes if n.type == "TEX_IMAGE" and n.image == im]:
                for out in node.outputs:
                    for link in list(out.links):
                        mat.node_tree.links.remove(link)
        dropped.append(im.name)
    return relinked, dropped


def _default_material():
    mat = bpy.data.materials.get(DEFAULT_MATERIAL)
    if mat is None:
        mat = bpy.data.materials.new(DEFAULT_MATERIAL)
        mat.use_nodes = True
        bsdf = next(n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
        bsdf.inputs["Base Color"].default_value = (0.18, 0.18, 0.18, 1.0)
        bsdf.inputs["Roughness"].default_value = 0.6
        mat.use_fake_user = True
    return mat


def _fill_materials(me) -> bool:
    """Give faces without a material (no slot, or an empty one) the neutral default; True if any."""
    if not len(me.polygons):
        return False
    if not len(me.materials):
        me.materials.append(_default_material())
        return True
    idx = np.empty(len(me.polygons), np.int32)
    me.polygons.foreach_get("material_index", idx)
    used = set(np.unique(np.clip(idx, 0, len(me.materials) - 1)).tolist())
    empty = [i for i in used if me.materials[i] is None]
    for i in empty:
        me.materials[i] = _default_material()
    return bool(empty)


RED_RES = 256  # texture resolution the red share is measured at


def _is_red(c: np.ndarray) -> np.ndarray:
    """Tail-lamp red in (display-referred) colours: R > 0.35, R > 2 G, R > 2 B."""
    return (c[..., 0] > 0.35) & (c[..., 0] > 2.0 * c[..., 1]) & (c[..., 0] > 2.0 * c[..., 2])


def _is_signal(c: np.ndarray) -> np.ndarray:
    """A signal lamp's red or green."""
    green = (c[..., 1] > 0.35) & (c[..., 1] > 1.5 * c[..., 0]) & (c[..., 1] > 1.1 * c[..., 2])
    return _is_red(c) | green


def _red_fraction(me, faces: np.ndarray, is_lamp=_is_red) -> np.ndarray:
    """The share of tail-lamp red in the base colour of the faces ``faces`` (indices) of ``me``:
    for a material with an image texture, the red texels inside the face's UV polygon (a lamp
    is often painted on a larger face), else whether its Base Color value is red."""
    out = np.zeros(len(faces))
    if not len(faces):
        return out
    n = len(me.polygons)
    mi = np.empty(n, np.int32)
    me.polygons.foreach_get("material_index", mi)
    uv = start = total = None
    if me.uv_layers.active is not None and len(me.loops):
        uv = np.empty(len(me.loops) * 2)
        me.uv_layers.active.data.foreach_get("uv", uv)
        uv = uv.reshape(-1, 2)
        start, total = np.empty(n, np.int64), np.empty(n, np.int64)
        me.polygons.foreach_get("loop_start", start)
        me.polygons.foreach_get("loop_total", total)
    masks = {}
    for j, f in enumerate(faces):
        k = min(int(mi[f]), len(me.materials) - 1)
        mat = me.materials[k] if k >= 0 else None
        if mat is None:
            continue
        if k not in masks:
            colour, image = _material_colour(mat)
            mask = None
            if image is not None and uv is not None and image.size[0] and image.size[1]:
                w, h = image.size
                px = np.empty(w * h * 4, np.float32)
                image.pixels.foreach_get(px)
                px = cv2.resize(px.reshape(h, w, 4)[..., :3], (RED_RES, RED_RES), interpolation=cv2.INTER_AREA)
                mask = is_lamp(px).astype(np.uint8)
            masks[k] = (float(is_lamp(np.asarray(colour))), mask)
        value, mask = masks[k]
        if mask is None:
            out[j] = value
            continue
        pts = uv[start[f]:start[f] + total[f]]
        pts = np.round(np.mod(pts, 1.0 + 1e-9) * (RED_RES - 1)).astype(np.int32)  # v up: row = v
        x0, y0 = pts.min(axis=0)
        x1, y1 = pts.max(axis=0) + 1
        poly = np.zeros((y1 - y0, x1 - x0), np.uint8)
        cv2.fillPoly(poly, [pts - (x0, y0)], 1)
        cnt = int(poly.sum())
        out[j] = float((mask[y0:y1, x0:x1] & poly).sum()) / cnt if cnt else float(mask[y0, x0])
    return out


def _material_colour(mat):
    """(Base Color value, the image texture feeding it or None) of a material's Principled BSDF."""
    if mat.node_tree is None:
        return np.array(mat.diffuse_color[:3]), None
    bsdf = next((n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED"), None)
    if bsdf is None:
        return np.array(mat.diffuse_color[:3]), None
    sock = bsdf.inputs["Base Color"]
    todo = [link.from_node for link in sock.links]
    for _ in range(4):  # an image may reach the BSDF through a mix or colour node
        img = next((nd for nd in todo if nd.type == "TEX_IMAGE" and nd.image is not None and nd.image.size[0] > 0), None)
        if img is not None:
            return np.array(sock.default_value[:3]), img.image
        todo = [link.from_node for nd in todo for i in nd.inputs for link in i.links]
    return np.array(sock.default_value[:3]), None


def front_by_lamps(parts, up: str, cls: str) -> tuple[str, str] | None:
    """An asset's front from its lamps' colours. A vehicle: the end of its long horizontal axis
    with the most red surface facing along that axis (within 12 % of the length of the end) is
    the rear (tail lamps). A traffic light: of the four horizontal ends, the one with the most
    red and green surface faces the traffic. (axis, how), or None when no end shows three
    times the red of the opposite one."""
    ui = "xyz".index(up[1])
    geo = []
    for me, M in parts:
        n = len(me.polygons)
        if not n:
            continue
        c, nr, ar = np.empty(n * 3), np.empty(n * 3), np.empty(n)
        me.polygons.foreach_get("center", c)
        me.polygons.foreach_get("normal", nr)
        me.polygons.foreach_get("area", ar)
        R = M[:3, :3]
        scale = abs(np.linalg.det(R)) ** (1 / 3) or 1.0
        geo.append((me, c.reshape(-1, 3) @ R.T + M[:3, 3], nr.reshape(-1, 3) @ R.T / scale, ar * scale ** 2))
    if not geo:
        return None
    allc = np.concatenate([g[1] for g in geo])
    lo, hi = allc.min(axis=0), allc.max(axis=0)
    horiz = [i for i in range(3) if i != ui]
    signal = cls == "traffic light"
    axes = horiz if signal else [max(horiz, key=lambda i: hi[i] - lo[i])]
    score = {}
    for ax in axes:
        L = hi[ax] - lo[ax]
        for me, ctr, nrm, area in geo:
            facing = np.abs(nrm[:, ax]) > 0.5 * np.maximum(np.linalg.norm(nrm, axis=1), 1e-9)
            for sign, end in ((+1, hi[ax]), (-1, lo[ax])):
                sel = np.flatnonzero(facing & (np.abs(ctr[:, ax] - end) < 0.12 * L))
                score[ax, sign] = score.get((ax, sign), 0.0) + float(
                    (area[sel] * _red_fraction(me, sel, _is_signal if signal else _is_red)).sum())
    (ax, sign), best = max(score.items(), key=lambda kv: kv[1])
    other = score[ax, -sign]
    if best <= 0 or best <= 3 * other:
        return None
    a = "xyz"[ax]
    end = ("+" if sign > 0 else "-") + a
    if signal:
        return end, f"signal lamps: red and green at the {end} end ({best:.3g} vs {other:.3g} model units^2)"
    front = ("-" if sign > 0 else "+") + a
    return front, f"tail lamps: red at the {end} end ({best:.3g} vs {other:.3g} model units^2)"


def _bounds(parts) -> tuple[np.ndarray, np.ndarray, int]:
    lo, hi, tris = np.full(3, np.inf), np.full(3, -np.inf), 0
    for me, M in parts:
        co = np.empty(len(me.vertices) * 3)
        me.vertices.foreach_get("co", co)
        w = co.reshape(-1, 3) @ M[:3, :3].T + M[:3, 3]
        lo, hi = np.minimum(lo, w.min(axis=0)), np.maximum(hi, w.max(axis=0))
        me.calc_loop_triangles()
        tris += len(me.loop_triangles)
    return lo, hi, tris


def _free(parts) -> None:
    for me in {id(me): me for me, _ in parts}.values():
        if me.users == 0:
            bpy.data.meshes.remove(me)


def inspect(ref: AssetRef) -> dict:
    """Import the asset once, measure it, and return its catalog entry (UserError if bad)."""
    spec = ref.spec
    with _Import(ref) as imp:
        parts = imp.parts()
        textures = imp.textures()
        missing = [t["file"] or t["name"] for t in textures if t["missing"]]
        lo, hi, tris = _bounds(parts) if parts else (None, None, 0)
        n_meshes = len(parts)
        front = front_by_lamps(parts, spec.up, spec.cls) if parts and spec.front is None and \
            spec.cls in VEHICLES + ("traffic light",) else None
        fixes = {"hidden_parts_skipped": imp.hidden(), "parts_without_material": imp.no_material,
                 "rigged_parts_posed": imp.rigged, "textures_relinked": imp.relinked,
                 "textures_missing_ignored": imp.dropped}
        _free(parts)
    if missing and spec.missing_textures != "ignore":
        raise UserError(f"missing texture {missing[0]!r}" + (f" (+{len(missing) - 1} more)" if len(missing) > 1 else ""),
                        where=ref.key)
    if not parts or tris == 0:
        raise UserError("no geometry: the asset has no mesh with faces" +
                        (f" in variant {ref.variant!r}" if ref.variant else ""), where=ref.key)
    norm = normalisation(spec, lo, hi, where=ref.key, front=front[0] if front else None,
                         front_source=front[1] if front else None)
    return {**ref.to_dict(), "key": ref.key, "cls": spec.cls, "licence": spec.licence,
            "mount_height_m": spec.mount_height_m, **norm, "meshes": n_meshes, "triangles": tris,
            "textures": [t["file"] or t["name"] for t in textures], **{k: v for k, v in fixes.items() if v}}


class AssetInspector:
    """Farm processor of the `assets` step. Item: the stem of the asset's result file
    (blendgen.job.assets.result_path, keyed by its fingerprint, so a changed asset is
    inspected again). A bad asset's result is {"error": ...}: the supervisor reports them
    all before planning."""

    def __init__(self, refs: list[dict], out_dir: str):
        self.dir = Path(out_dir)
        self.refs = {result_path(self.dir, ref).stem: ref for ref in (AssetRef(**r) for r in refs)}
        bpy.ops.wm.read_factory_settings(use_empty=True)

    def is_done(self, item: str) -> bool:
        return result_path(self.dir, self.refs[item]).exists()

    def process(self, item: str) -> dict:
        ref = self.refs[item]
        try:
            entry = inspect(ref)
        except UserError as e:
            msg = str(e)
            for prefix in (f"{ref.key}: ", f"{ref.file}: "):
                msg = msg.removeprefix(prefix)
            entry = {"key": ref.key, "file": ref.file, "error": msg}
        atomic.write_json(result_path(self.dir, ref), entry, indent=1)
        return {"stage": "assets", "item": item, "asset": ref.key, "error": entry.get("error")}


class AssetLibrary:
    """The warm session's cache: each file imported once, each variant baked once."""

    def __init__(self):
        self.templates: dict[tuple[str, str | None], list[tuple[object, Matrix]]] = {}

    def load(self, variant: dict) -> None:
        """Import what `variant` (from blendgen.job.assets.asset_variant) needs, if not cached."""
        key = (variant["file"], variant.get("node"))
        if key in self.templates:
            return
        node = variant.get("node")
        ref = AssetRef(variant["file"], variant["format"], node, {}, None, variant["fingerprint"])
        T = np.asarray(variant["transform"], float)
        with _Import(ref) as imp:
            parts = imp.parts()
        for me, _ in parts:
            me.use_fake_user = True  # the template outlives the instances that use it
        self.templates[key] = [(me, Matrix((T @ M).tolist())) for me, M in parts]

    def instance(self, obj: PlacedObject):
        """A placed instance: an empty root (origin at the bottom centre, pass_index = id) with
        one linked duplicate per template part."""
        parts = self.templates[(obj.variant["file"], obj.variant.get("node"))]
        name = f"obj_{obj.id}_{obj.cls.replace(' ', '_')}"
        root = bpy.data.objects.new(name, None)
        scene = bpy.context.scene
        scene.collection.objects.link(root)
        root.location = tuple(float(x) for x in obj.position)
        root.rotation_euler = obj.euler_xyz  # yaw, and the road's pitch/roll
        root.pass_index = int(obj.id)
        root["blendgen_id"] = int(obj.id)
        root["blendgen_cls"] = obj.cls
        root["blendgen_asset"] = obj.variant["asset"]
        for i, (me, M) in enumerate(parts):
            ob = bpy.data.objects.new(f"{name}_{i}", me)
            scene.collection.objects.link(ob)
            ob.parent = root
            ob.matrix_parent_inverse = Matrix.Identity(4)
            ob.matrix_basis = M
            ob.pass_index = int(obj.id)
        return root

