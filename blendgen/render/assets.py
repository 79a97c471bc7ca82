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
import numpy as np
from mathutils import Matrix

from blendgen import atomic
from blendgen.errors import UserError
from blendgen.scene.assets import AssetRef, normalisation, result_path
from blendgen.scene.plan import PlacedObject

MESHLIKE = {"MESH", "CURVE", "SURFACE", "META", "FONT"}
LIB_PREFIX = "blendgen_asset"


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
        self.objects = [o for o in bpy.data.objects if o not in before]
        self.images = [im for im in bpy.data.images if im not in images]
        for o in self.objects:  # importers may add to the scene collection too
            if self.coll not in o.users_collection:
                self.coll.objects.link(o)
        bpy.context.view_layer.update()
        return self

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
        dg = bpy.context.evaluated_depsgraph_get()
        baked: dict[tuple[str, str], object] = {}
        names = {o.name for o in self.objects}
        out = []
        for inst in dg.object_instances:
            ob = inst.object
            if ob.type not in MESHLIKE:
                continue
            # What draws it: the object itself, or the instancer (collection instance, geometry nodes)
            owner = (inst.parent if inst.is_instance else ob).original
            if owner.name not in names or (keep is not None and owner.name not in keep):
                continue
            # One baked mesh per source object and its evaluated data: every instance of it shares it.
            key = (ob.original.name, ob.data.name if ob.data is not None else "")
            if key not in baked:
                me = bpy.data.meshes.new_from_object(ob, preserve_all_data_layers=True, depsgraph=dg)
                me.name = f"{LIB_PREFIX}_{Path(self.ref.file).stem}_{key[0]}"
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
        for o in list(self.coll.all_objects):
            bpy.data.objects.remove(o, do_unlink=True)
        for c in list(self.coll.children_recursive):
            bpy.data.collections.remove(c)
        bpy.data.collections.remove(self.coll)
        return False


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
        _free(parts)
    if missing:
        raise UserError(f"missing texture {missing[0]!r}" + (f" (+{len(missing) - 1} more)" if len(missing) > 1 else ""),
                        where=ref.key)
    if not parts or tris == 0:
        raise UserError("no geometry: the asset has no mesh with faces" +
                        (f" in variant {ref.variant!r}" if ref.variant else ""), where=ref.key)
    norm = normalisation(spec, lo, hi, where=ref.key)
    return {**ref.to_dict(), "key": ref.key, "cls": spec.cls, "licence": spec.licence,
            "mount_height_m": spec.mount_height_m, **norm, "meshes": n_meshes, "triangles": tris,
            "textures": [t["file"] or t["name"] for t in textures]}


class AssetInspector:
    """Farm processor of the `assets` step. Item: the stem of the asset's result file
    (blendgen.scene.assets.result_path, keyed by its fingerprint, so a changed asset is
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
        """Import what `variant` (from blendgen.scene.assets.asset_variant) needs, if not cached."""
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

