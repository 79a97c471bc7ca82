"""A warm Blender (Cycles) session: build the twin once, then realise one FramePlan per call.

Imports bpy: only farm workers may import this module (see docs/architecture.md).
The decisions about what to render are bpy-free (effects.py); this module applies them.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import shutil
import tempfile
import time
import warnings
import weakref
import zlib
from pathlib import Path
from typing import Callable

import bpy
import numpy as np
from mathutils import Matrix, Vector

from blendgen.atomic import atomic_path
from blendgen.errors import StageError, UserError
from blendgen.geometry import Camera
from blendgen.plan import SCENERY_ID, FramePlan, PlacedObject
from blendgen.render import effects as fx
from blendgen.render import environment as plate_env
from blendgen.render import passes as passes_mod
from blendgen.render.exr import empty_passes, read_passes, write_passes
from blendgen.render.projection import blender_intrinsics, blender_matrix_world, make_canvas
from blendgen.render.raster import rasterize_mask

GROUND_ROLES = {"road", "sidewalk", "marking"}
HOLDOUT_ROLES = {"structure", "vegetation"}
STREET_GLINT_DEG = 3.0  # the street light as glass and clear coat mirror it: a lamp, not a 30 deg glow
# Data-block collections an object builder may fill; what it adds is removed with the object.
DATA_KINDS = ("objects", "meshes", "materials", "images", "textures", "node_groups", "curves",
              "lights", "actions")
MESHLIKE = {"MESH", "CURVE", "SURFACE", "META", "FONT"}


def _rss_mb() -> float:
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * 4096 / 2**20
    except OSError:
        return float("nan")


def noise_seed(frame: str) -> int:
    """Cycles' sampling seed for a frame without a job seed: fixed per frame (reruns are
    identical), different between frames (one seed for all gave every frame the same noise
    pattern, which the ego-motion step locked onto on rendered drives and a detector could learn)."""
    return zlib.crc32(str(frame).encode()) & 0x7FFFFFFF


class _Placed:
    """One realised PlacedObject: its Blender objects, its data blocks, its mesh for rasterising."""

    def __init__(self, key: str, root, blocks: dict[str, list[str]]):
        self.key = key
        self.root = root
        self.blocks = blocks
        self.tris_local: tuple[np.ndarray, np.ndarray] | None = None

    def hierarchy(self):
        return [self.root, *self.root.children_recursive]


class RenderSession:
    """See docs/render.md. `object_builder`/`twin_builder` default to assets_procedural's.

    One Blender scene per process: a new session resets it, so the previous session of the
    same process stops working (it raises instead of rendering a foreign scene).
    """

    _current: "RenderSession | None" = None

    def __init__(self, twin_path: Path | None, ground_plane, render, camera: Camera, *,
                 object_builder: Callable[[PlacedObject], object] | None = None,
                 twin_builder: Callable[[], object] | None = None, catch_shadows_on: str = "patches"):
        t0 = time.perf_counter()
        self.render = render
        if render.resolution is not None and tuple(render.resolution) != (camera.width, camera.height):
            camera = camera.scaled(*render.resolution)
        self.camera = camera
        self.canvas = make_canvas(camera)
        self._object_builder = object_builder
        if catch_shadows_on not in ("patches", "ground"):
            raise ValueError(f"catch_shadows_on: expected 'patches' or 'ground', got {catch_shadows_on!r}")
        # "ground" (the whole road catches shadows) is the naive baseline the benchmark measures.
        self.catch_shadows_on = catch_shadows_on
        self._placed: dict[int, _Placed] = {}
        self._assets = None  # blendgen.render.assets.AssetLibrary, made on the first library asset
        self._tmp = Path(tempfile.mkdtemp(prefix="blendgen_render_"))
        # Removed on close(), or when the session is collected / the worker exits.
        self._tmp_cleanup = weakref.finalize(self, shutil.rmtree, str(self._tmp), True)
        self._frames = 0

        bpy.ops.wm.read_factory_settings(use_empty=True)
        RenderSession._current = self
        self.scene = sc = bpy.context.scene
        self.view_layer = sc.view_layers[0]
        self._setup_render()
        self._setup_camera()
        self._setup_lights()
        self._ground = None
        self._catcher = None
        if twin_builder is not None:
            twin_builder()
        elif twin_path is not None:
            self._build_twin(Path(twin_path))
        else:
            from blendgen.render.primitives import ground_plane as make_ground

            self._ground = make_ground()
        self._roles = {ob.name: ob.get("blendgen_role") for ob in sc.objects if ob.get("blendgen_role")}
        self.twin_objects = [ob for ob in sc.objects if ob.name in self._roles]
        self.setup_s = time.perf_counter() - t0

    # ------------------------------------------------------------------ setup
    def _setup_render(self):
        sc, r = self.scene, self.render
        sc.render.engine = "CYCLES"
        cy = sc.cycles
        cy.device = "CPU"
        self.device = "CPU"
        if r.device == "GPU":
            self.device = self._enable_gpu()
        if r.threads:
            sc.render.threads_mode = "FIXED"
            sc.render.threads = int(r.threads)
        sc.render.use_persistent_data = True  # keep the BVH and shaders between frames
        sc.render.resolution_percentage = 100
        sc.render.use_crop_to_border = True  # Blender writes only the region; we place it
        sc.render.film_transparent = True
        sc.view_settings.view_transform = "Standard"  # PNG previews in plain sRGB
        cy.use_light_tree = False
        cy.pixel_filter_type = "BLACKMAN_HARRIS"
        cy.denoiser = "OPENIMAGEDENOISE"
        cy.denoising_input_passes = "RGB_ALBEDO_NORMAL"
        cy.denoising_prefilter = "FAST"
        # OIDN's fast network: on the bench_render frame 1.0 -> 0.6 CPU s per frame at +0.05 dB
        # (day) / -0.23 dB (overcast, lamps on) against BALANCED (docs/render.md)
        cy.denoising_quality = "FAST"
        cy.seed = 0  # set per frame (noise_seed)
        # Motion-blur keys must interpolate linearly (constant velocity over the shutter).
        bpy.context.preferences.edit.keyframe_new_interpolation_type = "LINEAR"
        ims = sc.render.image_settings
        ims.media_type = "MULTI_LAYER_IMAGE"
        ims.file_format = "OPEN_EXR_MULTILAYER"
        ims.color_depth = "32"
        ims.exr_codec = "NONE"  # a temp file read back at once: compressing it costs time only
        self.view_layer.use_pass_combined = True

    def _enable_gpu(self) -> str:
        try:
            prefs = bpy.context.preferences.addons["cycles"].preferences
            for kind in ("OPTIX", "CUDA", "HIP", "ONEAPI", "METAL"):
                try:
                    prefs.compute_device_type = kind
                except TypeError:
                    continue
                prefs.get_devices()
                devs = [d for d in prefs.devices if d.type == kind]
                if devs:
                    for d in prefs.devices:
                        d.use = d.type == kind
                    self.scene.cycles.device = "GPU"
                    # Blender's default denoises on the CPU even when rendering on a GPU: on an H200
                    # that made OIDN most of a frame's wall time (docs/benchmarks/render_gpu.md)
                    self.scene.cycles.denoising_use_gpu = True
                    return f"GPU ({kind})"
        except Exception:  # no GPU backend in this build/machine: CPU is the right answer
            pass
        return "CPU (no GPU found)"

    def _setup_camera(self):
        sc = self.scene
        pin = self.canvas.pinhole
        b = blender_intrinsics(pin)
        data = bpy.data.cameras.new("blendgen_camera")
        data.sensor_fit = b["sensor_fit"]
        data.sensor_width = b["sensor_width"]
        data.sensor_height = b["sensor_height"]
        data.lens = b["lens"]
        data.shift_x, data.shift_y = b["shift_x"], b["shift_y"]
        data.clip_start, data.clip_end = 0.05, 5000.0
        self.cam_ob = bpy.data.objects.new("blendgen_camera", data)
        sc.collection.objects.link(self.cam_ob)
        sc.camera = self.cam_ob
        sc.render.resolution_x, sc.render.resolution_y = b["resolution"]
        sc.render.pixel_aspect_x, sc.render.pixel_aspect_y = b["pixel_aspect"]

    def _setup_lights(self):
        sc = self.scene
        sun = bpy.data.lights.new("blendgen_sun", "SUN")
        self.sun = bpy.data.objects.new("blendgen_sun", sun)
        sc.collection.objects.link(self.sun)
        # Night/dusk key (lighting["street_light"]): a soft overhead lamp instead of the sun.
        self.street = bpy.data.objects.new("blendgen_street_light", bpy.data.lights.new("blendgen_street_light", "SUN"))
        # Its 30 deg source gives soft shading and contact shadows, but mirrored in glass and
        # clear coat it was a broad bright patch (night car windows lighter than their bodies):
        # glossy rays see a small lamp instead, the same light from a 3 deg source, no shadow.
        self.street.visible_glossy = False
        self.glint = bpy.data.objects.new("blendgen_street_glint", bpy.data.lights.new("blendgen_street_glint", "SUN"))
        self.glint.visible_diffuse = self.glint.visible_transmission = self.glint.visible_volume_scatter = False
        self.glint.data.use_shadow = False
        self.glint.data.angle = math.radians(STREET_GLINT_DEG)
        for ob in (self.street, self.glint):
            sc.collection.objects.link(ob)
            ob.hide_render = True
        # Night/dusk street lamps (effects.street_lamps): point lights that light the objects
        # only; the overhead key then lights only the ground's catcher, for the soft contact
        # shadow it gave before (light linking: the lamps exclude the ground, the key includes it).
        self.lamps: list = []
        self._ground_in = bpy.data.collections.new("blendgen_ground_include")
        self._ground_out = bpy.data.collections.new("blendgen_ground_exclude")
        world = bpy.data.worlds.new("blendgen_world")
        sc.world = world
        # No importance map: the renders are bit-identical without it (the light the world casts
        # is uniform), and with the frame's environment map (render.environment) in the world
        # Cycles rebuilt one for every frame: 0.13 -> 0.58 s per 480x270 demo frame.
        world.cycles.sampling_method = "NONE"
        with warnings.catch_warnings():  # deprecated in 5.0 but still needed for a new world
            warnings.simplefilter("ignore", DeprecationWarning)
            world.use_nodes = True
        nt = world.node_tree
        nt.nodes.clear()
        out = nt.nodes.new("ShaderNodeOutputWorld")
        bg = nt.nodes.new("ShaderNodeBackground")         # uniform sky: lights the objects
        sky = nt.nodes.new("ShaderNodeBackground")        # gradient: what a camera sees
        mirrored = nt.nodes.new("ShaderNodeBackground")   # what glossy rays see (lighting["reflected_strength"])
        mix = nt.nodes.new("ShaderNodeMixShader")
        gmix = nt.nodes.new("ShaderNodeMixShader")
        lp = nt.nodes.new("ShaderNodeLightPath")
        tc = nt.nodes.new("ShaderNodeTexCoord")
        sep = nt.nodes.new("ShaderNodeSeparateXYZ")
        ramp = nt.nodes.new("ShaderNodeValToRGB")
        nt.links.new(tc.outputs["Generated"], sep.inputs[0])
        nt.links.new(sep.outputs["Z"], ramp.inputs["Fac"])
        nt.links.new(ramp.outputs["Color"], sky.inputs["Color"])
        nt.links.new(lp.outputs["Is Glossy Ray"], gmix.inputs["Fac"])
        nt.links.new(bg.outputs[0], gmix.inputs[1])
        nt.links.new(mirrored.outputs[0], gmix.inputs[2])
        nt.links.new(lp.outputs["Is Camera Ray"], mix.inputs["Fac"])
        nt.links.new(gmix.outputs[0], mix.inputs[1])
        nt.links.new(sky.outputs[0], mix.inputs[2])
        nt.links.new(mix.outputs[0], out.inputs["Surface"])
        # What glossy rays see of a real frame's surround (render.environment), when given.
        env = nt.nodes.new("ShaderNodeTexEnvironment")
        w, h = plate_env.MAP_SIZE
        env.image = bpy.data.images.new("blendgen_plate_environment", w, h, float_buffer=True, alpha=False)
        self._world_nodes = {"bg": bg, "sky": sky, "mirrored": mirrored, "ramp": ramp, "env": env}

    def _build_twin(self, twin_path: Path):
        try:
            from assets_procedural.twin_builder import build_twin
            from blendgen.twin.model import load_twin
        except ImportError as e:
            raise StageError(f"cannot build the twin {twin_path}: {e}") from None
        if not twin_path.is_file():
            raise UserError("twin YAML not found", where=str(twin_path))
        self.twin_info = build_twin(load_twin(twin_path))

    # ------------------------------------------------------------------ per frame state
    def _apply_lighting(self, lighting: dict, *, background: bool, environment: np.ndarray | None = None):
        sun_dir = fx.sun_direction(lighting)
        sun = self.sun
        if sun_dir is None:
            sun.hide_render = True
        else:
            sun.hide_render = False
            # A sun lamp shines along its local -z: point local +z at the sun.
            sun.rotation_euler = Vector(sun_dir).to_track_quat("Z", "Y").to_euler()
            sun.data.energy = float(lighting.get("sun_strength", 3.0))
            sun.data.color = tuple(float(c) for c in lighting.get("sun_color", (1, 1, 1)))[:3]
            sun.data.angle = math.radians(float(lighting.get("sun_angle_deg", 0.53)))
        street = lighting.get("street_light")
        self.street.hide_render = self.glint.hide_render = not street
        if street:
            for ob in (self.street, self.glint):
                ob.rotation_euler = Vector(street["direction"]).to_track_quat("Z", "Y").to_euler()
                ob.data.energy = float(street["strength"])
                ob.data.color = tuple(float(c) for c in street["color"])[:3]
            self.street.data.angle = math.radians(float(street.get("angle_deg", 30.0)))
        sky = np.asarray(lighting.get("sky_color", (0.6, 0.7, 0.9)), dtype=float)[:3]
        strength = float(lighting.get("sky_strength", 1.0))
        n = self._world_nodes
        n["bg"].inputs["Color"].default_value = (*sky, 1.0)
        n["bg"].inputs["Strength"].default_value = strength
        reflected = lighting.get("reflected_strength")
        n["mirrored"].inputs["Color"].default_value = (*sky, 1.0)
        n["mirrored"].inputs["Strength"].default_value = strength if reflected is None else float(reflected)
        self._set_environment(environment)
        # Camera-ray sky for opaque backgrounds: paler at the horizon, the sky colour above.
        horizon = 0.5 * sky + 0.5 * float(sky.mean()) + 0.1
        ramp = n["ramp"].color_ramp
        ramp.elements[0].position, ramp.elements[1].position = 0.5, 0.8
        ramp.elements[0].color = (*horizon, 1.0)
        ramp.elements[1].color = (*(sky * 0.8), 1.0)
        n["sky"].inputs["Strength"].default_value = strength if background else 0.0

    def _camera_height(self, plan) -> float:
        """The camera's height above the road under it (the ground-plane twin's road is z = 0)."""
        return float(np.asarray(plan.T_world_cam)[2, 3]) if self._ground is not None else 1.5

    def _set_street_lamps(self, lamps: list[dict], beams: list[dict] = ()):
        """Point lamps at the given places (effects.street_lamps) and the camera car's low beams
        (effects.ego_headlights); none by day. With lamps the overhead street key lights the
        ground (its catcher) alone and the glint goes: the lamps light the objects and make
        their highlights. Neither lamps nor beams light the ground: the real frame shows its light."""
        while len(self.lamps) < len(lamps):
            ob = bpy.data.objects.new(f"blendgen_lamp{len(self.lamps)}",
                                      bpy.data.lights.new(f"blendgen_lamp{len(self.lamps)}", "POINT"))
            self.scene.collection.objects.link(ob)
            ob.light_linking.receiver_collection = self._ground_out
            self.lamps.append(ob)
        for ob, lamp in zip(self.lamps, lamps):
            ob.hide_render = False
            ob.location = tuple(lamp["position"])
            ob.data.energy = float(lamp["power_w"])
            ob.data.color = tuple(lamp["color"])
            ob.data.shadow_soft_size = float(lamp["radius_m"])
        for ob in self.lamps[len(lamps):]:
            ob.hide_render = True
        if not hasattr(self, "beams"):
            self.beams = []
            for i in range(2):
                ob = bpy.data.objects.new(f"blendgen_headlight{i}", bpy.data.lights.new(f"blendgen_headlight{i}", "SPOT"))
                self.scene.collection.objects.link(ob)
                ob.light_linking.receiver_collection = self._ground_out
                ob.data.shadow_soft_size = 0.08
                # light, not glare: a mirror-like rear window ahead would show the beams as a
                # hot spot the real frame's exposure does not (the camera sits behind them)
                ob.visible_glossy = False
                self.beams.append(ob)
        for ob, beam in zip(self.beams, list(beams) + [None] * len(self.beams)):
            ob.hide_render = beam is None
            if beam is None:
                continue
            ob.location = tuple(beam["position"])
            # a spot shines along its local -z
            ob.rotation_euler = (-Vector(beam["direction"])).to_track_quat("Z", "Y").to_euler()
            ob.scale = (1.0, float(beam.get("flat", 1.0)), 1.0)  # local y is up: a flat-topped beam
            ob.data.energy = float(beam["power_w"])
            ob.data.color = tuple(beam["color"])
            ob.data.spot_size = math.radians(float(beam["spot_deg"]))
            ob.data.spot_blend = float(beam["blend"])
        if lamps or beams:
            self._link_ground()
        if lamps:
            self.glint.hide_render = True
        self.street.light_linking.receiver_collection = self._ground_in if lamps else None

    def _link_ground(self):
        """The ground's objects (the catcher, the ground plane, a twin's road surfaces) in the two
        light-linking collections: included by the street key, excluded by the lamps."""
        ground = [ob for ob in (self._catcher, self._ground) if ob is not None]
        ground += [ob for ob in self.twin_objects if self._roles.get(ob.name) in GROUND_ROLES]
        for coll, state in ((self._ground_in, "INCLUDE"), (self._ground_out, "EXCLUDE")):
            for ob in ground:
                if ob.name not in coll.objects:
                    coll.objects.link(ob)
            for ob, entry in zip(coll.objects, coll.collection_objects):  # the same order
                entry.light_linking.link_state = state

    def _set_environment(self, environment: np.ndarray | None):
        """Glossy rays see `environment` (plate_env.plate_environment: rows from the top, linear
        RGB in render units) or, without one, the uniform sky of the lighting."""
        n, nt = self._world_nodes, self.scene.world.node_tree
        colour = n["mirrored"].inputs["Color"]
        for link in list(colour.links):
            nt.links.remove(link)
        if environment is None:
            return
        img = n["env"].image
        h, w = environment.shape[:2]
        if (w, h) != tuple(img.size):
            img.scale(w, h)
        rgba = np.ones((h, w, 4), np.float32)
        rgba[..., :3] = environment[::-1]  # Blender stores the bottom row first
        img.pixels.foreach_set(rgba.ravel())
        img.update()
        nt.links.new(n["env"].outputs["Color"], colour)
        n["mirrored"].inputs["Strength"].default_value = 1.0  # the frame is in render units

    def _set_twin_mode(self, mode: str, catcher: bool):
        """mode 'composite': structures holdout, ground catches shadows (or is hidden);
        mode 'background': the twin rendered as itself."""
        for ob in self.twin_objects:
            role = self._roles.get(ob.name)
            if mode == "background":
                ob.is_holdout, ob.is_shadow_catcher, ob.hide_render = False, False, False
                ob.visible_shadow = ob.visible_camera = True
                continue
            if role in GROUND_ROLES and self.catch_shadows_on == "ground":
                ob.is_holdout, ob.is_shadow_catcher, ob.hide_render = False, catcher, not catcher
                ob.visible_camera = True
            elif role in GROUND_ROLES:
                # Shadows are caught by per-frame patches where they can fall (catcher_patches);
                # camera rays on the rest of the ground would only cost shadow-catcher samples.
                # The ground stays for the light it bounces onto the objects (and reflections),
                # but casts no shadow: a map twin's ground meshes (its roads sit up to 1.7 cm above
                # z = 0) shadowed the patches whole (the demo town's catcher was ~0 under every
                # object).
                ob.is_holdout, ob.is_shadow_catcher, ob.hide_render = False, False, not catcher
                ob.visible_camera = ob.visible_shadow = False
            elif role in HOLDOUT_ROLES:
                ob.is_holdout, ob.is_shadow_catcher, ob.hide_render = True, False, False
                # Real structures already shadow the real road; do not darken it twice.
                ob.visible_shadow = False
            else:  # sky domes and anything unknown: the real frame supplies them
                ob.hide_render = True

    def _set_catcher(self, polygons: list[np.ndarray] | None):
        """Rebuild the shadow-catcher patch mesh in place (one data block for the session)."""
        if self._catcher is None:
            me = bpy.data.meshes.new("blendgen_catcher")
            self._catcher = bpy.data.objects.new("blendgen_catcher", me)
            self.scene.collection.objects.link(self._catcher)
            self._catcher.is_shadow_catcher = True
            self._catcher.data.materials.append(self._catcher_material())
        me = self._catcher.data
        me.clear_geometry()
        if not polygons:
            self._catcher.hide_render = True
            return
        verts, faces = [], []
        for poly in polygons:
            faces.append(tuple(range(len(verts), len(verts) + len(poly))))
            lift = fx.catcher_lift_m(poly) + self._ground_clearance(poly)
            verts.extend((float(x), float(y), float(z) + lift) for x, y, z in poly)
        me.from_pydata(verts, [], faces)
        me.update()
        self._catcher.hide_render = False

    @functools.cached_property
    def _ground_bvh(self):
        """The twin's ground surfaces (they never move) as one BVH tree, built when the first
        catcher patch needs it; None without a twin."""
        from mathutils.bvhtree import BVHTree

        self.view_layer.update()  # matrix_world of objects a builder has just placed
        verts, polys = [], []
        for ob in self.twin_objects:
            if ob is self._ground or ob.type != "MESH" or self._roles.get(ob.name) not in GROUND_ROLES:
                continue
            me = ob.data
            co = np.empty(3 * len(me.vertices))
            me.vertices.foreach_get("co", co)
            M = np.array(ob.matrix_world)
            base = len(verts)
            verts.extend((co.reshape(-1, 3) @ M[:3, :3].T + M[:3, 3]).tolist())
            polys.extend([base + i for i in p.vertices] for p in me.polygons)
        return BVHTree.FromPolygons(verts, polys) if polys else None

    def _ground_clearance(self, poly: np.ndarray) -> float:
        """How far the twin's ground stands above a patch's base height under it (<= 3 cm). A
        map twin layers its surfaces millimetres apart (the demo town's crossing road 1-2 mm
        over the main road); a patch under one caught no light, and its shadows were black."""
        if self._ground_bvh is None:
            return 0.0
        pts = np.vstack([poly, poly.mean(axis=0)])
        up = 0.0
        for x, y, z in pts:
            hit = self._ground_bvh.ray_cast(Vector((x, y, z + 0.03)), Vector((0.0, 0.0, -1.0)), 0.03)[0]
            if hit is not None:
                up = max(up, hit.z - z)
        return up

    def _catcher_material(self):
        from blendgen.render.primitives import material

        return material("blendgen_catcher", self._road_color(), roughness=0.9)

    def _road_color(self) -> tuple[float, float, float]:
        """Mean viewport colour of the twin's road surfaces (what the patches stand in for).

        The patch's albedo sets how much light the objects bounce onto the road in the caught
        passes: with 0.3 on a 0.25 ground plane the frame of bench_render was 0.46 dB off the
        render that catches on the ground itself (docs/render.md)."""
        cols = [ms.material.diffuse_color[:3] for ob in self.twin_objects
                if self._roles.get(ob.name) == "road" and ob.get("blendgen_kind") != "terrain"
                for ms in ob.material_slots if ms.material]
        return tuple(float(c) for c in np.mean(cols, axis=0)) if cols else (0.25, 0.25, 0.25)

    def _set_camera(self, T_world_cam):
        self.cam_ob.matrix_world = Matrix(blender_matrix_world(T_world_cam).tolist())
        if self._ground is not None:  # the ground plane follows the camera (flat world)
            t = np.asarray(T_world_cam, dtype=float)[:3, 3]
            self._ground.location = (float(t[0]), float(t[1]), 0.0)

    def _build(self, obj: PlacedObject):
        if self._object_builder is None:
            try:
                from assets_procedural.objects import build_object
            except ImportError as e:
                raise StageError(f"cannot build objects: {e}") from None
            self._object_builder = build_object
        builder = self._object_builder
        if obj.variant.get("asset"):  # a user library asset (docs/assets.md)
            from blendgen.render.assets import AssetLibrary

            self._assets = self._assets or AssetLibrary()
            self._assets.load(obj.variant)  # cached for the session, outside the object's blocks
            builder = self._assets.instance
        before = {k: set(getattr(bpy.data, k).keys()) for k in DATA_KINDS}
        root = builder(obj)
        if root is None:
            raise StageError(f"object builder returned nothing for object {obj.id} ({obj.cls})")
        blocks = {k: sorted(set(getattr(bpy.data, k).keys()) - before[k]) for k in DATA_KINDS}
        for ob in [root, *root.children_recursive]:
            if ob.name not in self.scene.objects:
                self.scene.collection.objects.link(ob)
            ob.pass_index = int(obj.id) + (SCENERY_ID if ob.get("blendgen_scenery") else 0)
        return root, blocks

    def _remove(self, placed: _Placed):
        for ob in reversed(placed.hierarchy()):
            if ob.name in bpy.data.objects:
                bpy.data.objects.remove(ob, do_unlink=True)
        for kind in DATA_KINDS[1:] + ("objects",):
            coll = getattr(bpy.data, kind)
            for name in placed.blocks.get(kind, []):
                block = coll.get(name)
                if block is not None and block.users == 0:
                    coll.remove(block)

    def _sync_objects(self, plan: FramePlan, kept_ids: set[int]) -> dict:
        """Add/move/remove objects so the scene holds exactly the kept objects of the plan."""
        stats = {"built": 0, "reused": 0, "removed": 0, "hidden": 0}
        by_id = {int(o.id): o for o in plan.objects}
        for oid in list(self._placed):
            o = by_id.get(oid)
            if o is None or self._key(o) != self._placed[oid].key:
                self._remove(self._placed.pop(oid))
                stats["removed"] += 1
        for oid, o in by_id.items():
            p = self._placed.get(oid)
            if oid not in kept_ids:
                if p is not None:  # culled this frame: keep it for when it comes back
                    for ob in p.hierarchy():
                        ob.hide_render = True
                    stats["hidden"] += 1
                continue
            if p is None:
                root, blocks = self._build(o)
                p = self._placed[oid] = _Placed(self._key(o), root, blocks)
                stats["built"] += 1
            else:
                stats["reused"] += 1
            for ob in p.hierarchy():
                ob.hide_render = False
            p.root.location = tuple(float(c) for c in o.position)
            p.root.rotation_mode = "XYZ"
            p.root.rotation_euler = o.euler_xyz  # yaw, and the road's pitch/roll
        return stats

    @staticmethod
    def _key(o: PlacedObject) -> str:
        return json.dumps([o.cls, list(map(float, o.dims)), o.variant, o.state], sort_keys=True, default=str)

    def _hide_objects(self, hide: bool):
        for p in self._placed.values():
            for ob in p.hierarchy():
                ob.hide_render = hide

    # ------------------------------------------------------------------ motion blur
    def _keyframe_motion(self, plan: FramePlan, ids, shutter_s: float):
        """Linear motion over the shutter: keys at frames 0 and 2, rendered at frame 1 with a
        one-frame shutter, so the exposure spans position -/+ velocity * shutter / 2. The
        velocity is relative to the camera (which stays put): the same image motion as both
        moving."""
        sc = self.scene
        by_id = {int(o.id): o for o in plan.objects}
        v_cam = np.asarray(plan.camera_velocity, dtype=float)
        for oid in ids:
            o, p = by_id[oid], self._placed[oid]
            v = np.asarray(o.velocity, dtype=float) - v_cam
            pos = np.asarray(o.position, dtype=float)
            for frame, sign in ((0, -1.0), (2, 1.0)):
                p.root.location = tuple(pos + sign * v * shutter_s)
                p.root.keyframe_insert("location", frame=frame)
        sc.frame_set(1)
        sc.render.use_motion_blur = True
        sc.render.motion_blur_shutter = 1.0
        sc.render.motion_blur_position = "CENTER"

    def _clear_motion(self, plan: FramePlan, ids):
        by_id = {int(o.id): o for o in plan.objects}
        for oid in ids:
            p = self._placed[oid]
            action = p.root.animation_data.action if p.root.animation_data else None
            p.root.animation_data_clear()
            if action is not None and action.users == 0:
                bpy.data.actions.remove(action)
            p.root.location = tuple(float(c) for c in by_id[oid].position)
        self.scene.render.use_motion_blur = False

    # ------------------------------------------------------------------ passes and sampling
    def _set_passes(self, keys: list[str]):
        vl = self.view_layer
        lighting = {"diffuse_direct", "diffuse_indirect", "diffuse_color",
                    "glossy_direct", "glossy_indirect", "glossy_color"}
        vl.use_pass_object_index = "index" in keys
        vl.use_pass_z = "depth" in keys
        vl.cycles.use_pass_shadow_catcher = "shadow_catcher" in keys
        for k in lighting:
            setattr(vl, f"use_pass_{k}", k in keys)

    def _set_sampling(self, s: dict):
        cy = self.scene.cycles
        cy.samples = s["samples"]
        cy.use_adaptive_sampling = s["adaptive"]
        cy.adaptive_threshold = s["adaptive_threshold"]
        cy.adaptive_min_samples = 0
        cy.use_denoising = s["denoise"]
        cy.max_bounces = s["max_bounces"]
        cy.diffuse_bounces = s["diffuse_bounces"]
        cy.glossy_bounces = s["glossy_bounces"]
        cy.transmission_bounces = s["transmission_bounces"]
        cy.transparent_max_bounces = s["transparent_bounces"]
        cy.volume_bounces = s["volume_bounces"]
        cy.caustics_reflective = cy.caustics_refractive = s["caustics"]
        cy.sample_clamp_indirect = s["clamp_indirect"]

    def _set_region(self, region):
        r = self.scene.render
        if region is None:
            r.use_border = False
            return
        pin = self.canvas.pinhole
        r.use_border = True
        r.border_min_x, r.border_max_x, r.border_min_y, r.border_max_y = fx.border_fractions(
            region, pin.width, pin.height)

    # ------------------------------------------------------------------ amodal masks
    def _tris_local(self, p: _Placed) -> tuple[np.ndarray, np.ndarray]:
        """The object's triangles in its root frame (cached: reused objects are rigid)."""
        if p.tris_local is not None:
            return p.tris_local
        depsgraph = bpy.context.evaluated_depsgraph_get()
        inv_root = np.array(p.root.matrix_world.inverted())
        verts, tris, n = [], [], 0
        for ob in p.hierarchy():
            if ob.type not in MESHLIKE or ob.get("blendgen_scenery"):
                continue
            ev = ob.evaluated_get(depsgraph)
            me = ev.to_mesh()
            try:
                me.calc_loop_triangles()
                co = np.empty(len(me.vertices) * 3, np.float64)
                me.vertices.foreach_get("co", co)
                tri = np.empty(len(me.loop_triangles) * 3, np.int64)
                me.loop_triangles.foreach_get("vertices", tri)
            finally:
                ev.to_mesh_clear()
            M = inv_root @ np.array(ob.matrix_world)
            co = co.reshape(-1, 3) @ M[:3, :3].T + M[:3, 3]
            verts.append(co)
            tris.append(tri.reshape(-1, 3) + n)
            n += len(co)
        p.tris_local = ((np.concatenate(verts) if verts else np.zeros((0, 3))),
                        (np.concatenate(tris) if tris else np.zeros((0, 3), np.int64)))
        return p.tris_local

    def _amodal(self, plan: FramePlan, ids) -> dict[int, int]:
        bpy.context.view_layer.update()
        out = {}
        for oid in ids:
            p = self._placed[oid]
            v_local, tris = self._tris_local(p)
            M = np.array(p.root.matrix_world)
            v_world = v_local @ M[:3, :3].T + M[:3, 3]
            mask = rasterize_mask(self.canvas.pinhole, plan.T_world_cam, v_world, tris)
            mask = self.canvas.to_output(mask, nearest=True)
            out[oid] = int(np.count_nonzero(mask))
        return out

    # ------------------------------------------------------------------ public API
    def _check_current(self):
        if RenderSession._current is not self:
            raise StageError("this RenderSession was closed or replaced by a newer one in this process")

    def render_frame(self, plan: FramePlan, out_exr: Path, outputs: set[str], *, compression: str = "zip",
                     environment=None, seed: int | None = None) -> dict:
        """See docs/render.md. `compression`: the EXR codec (exr.COMPRESSIONS, lossless); "none"
        when the caller reads the file once and deletes it. `environment`: what glass and clear
        coat mirror (plate_env.plate_environment of the real frame), or a function that makes it
        (called only when the frame is rendered); None: the lighting's sky. `seed`: Cycles'
        sampling seed (the job's frame seed, so that frame k of two drives or two job seeds
        does not share its noise); None: `noise_seed(plan.frame_id)`."""
        self._check_current()
        t0 = time.perf_counter()
        timings: dict[str, float] = {}
        outputs = set(outputs)
        lighting_src = "plan" if plan.lighting else "default (the plan has no lighting estimate)"
        lighting = plan.lighting or fx.DEFAULT_LIGHTING
        plan_l = dataclasses.replace(plan, lighting=lighting)
        try:
            eff = fx.decide_effects(plan_l, self.canvas.pinhole, self.render, outputs,
                                    gpu=self.device.startswith("GPU"))
        except ValueError as e:
            raise UserError(str(e), where=f"frame {plan.frame_id}") from None
        timings["decide"] = time.perf_counter() - t0
        keys = eff.passes.value
        W, H = self.camera.width, self.camera.height
        info = {"frame_id": plan.frame_id, "decisions": eff.to_dict(), "lighting": lighting_src,
                "device": self.device, "canvas": [self.canvas.pinhole.width, self.canvas.pinhole.height],
                "amodal_method": "mesh triangles rasterised at pixel centres in NumPy (no render)"}
        if eff.skip_render.value:
            t1 = time.perf_counter()
            kept = set()
            self._sync_objects(plan, kept)  # hide culled objects that exist
            write_passes(out_exr, empty_passes(W, H, keys), window=(0, 0, 1, 1), compression=compression)
            timings["write"] = time.perf_counter() - t1
            timings["total"] = time.perf_counter() - t0
            info.update(region=None, amodal_px={}, skipped=True,
                        timings={k: round(v, 4) for k, v in timings.items()}, rss_mb=round(_rss_mb(), 1))
            return info

        t1 = time.perf_counter()
        kept = set(eff.objects.value)
        by_id_all = {int(o.id): o for o in plan.objects}
        info["objects"] = self._sync_objects(plan, kept)
        self._set_camera(plan.T_world_cam)
        self.scene.cycles.seed = noise_seed(plan.frame_id) if seed is None else int(seed) & 0x7FFFFFFF
        if callable(environment):
            environment = environment()
        self._apply_lighting(lighting, background=False, environment=environment)
        info["reflections"] = "the real frame" if environment is not None else "the lighting's uniform sky"
        info["lamps_on"] = bool(lighting.get("lights_on", False))  # head/tail lamps: night and dusk
        from assets_procedural.materials import set_vehicle_lamps

        set_vehicle_lamps(info["lamps_on"])
        self._set_twin_mode("composite", catcher=bool(eff.shadow_catcher.value))
        by_id = {int(o.id): o for o in plan.objects}
        margin = fx.SUN_MARGIN_M if fx.sun_direction(lighting) is not None else fx.SOFT_MARGIN_M
        patches = (fx.catcher_patches([by_id[i] for i in sorted(kept)], fx.shadow_light_direction(lighting), margin)
                   if eff.shadow_catcher.value and self.catch_shadows_on == "patches" else None)
        self._set_catcher(patches)
        lamps = fx.street_lamps([by_id_all[i] for i in sorted(kept) if i in by_id_all], plan.T_world_cam,
                                lighting.get("street_light"))
        beams = fx.ego_headlights(plan.T_world_cam, lighting.get("street_light"),
                                  ground_z=float(np.asarray(plan.T_world_cam)[2, 3]) - self._camera_height(plan))
        self._set_street_lamps(lamps, beams)  # after the catcher: the lamps leave it to the street key
        if lamps:
            info["street_lamps"] = lamps
        if beams:
            info["headlights"] = beams
        if patches is not None:
            info["decisions"]["shadow_catcher"]["reason"] += (
                f"; caught on {len(patches)} ground patches (footprint + shadow of each object)")
        self.scene.render.film_transparent = True
        self._set_passes(keys)
        self._set_sampling(eff.sampling.value)
        movers = [i for i, px in eff.blur_px.items() if px > 0] if eff.motion_blur.value else []
        if movers:
            self._keyframe_motion(plan, movers, eff.shutter_s)
        timings["scene"] = time.perf_counter() - t1

        # One border render per cluster of objects (effects.cluster_boxes), the scene synced
        # once: objects far apart do not pay for the empty frame between them.
        regions = eff.regions
        t2 = time.perf_counter()
        raws = []
        try:
            for i, region in enumerate(regions or [None]):
                tmp = self._tmp / f"frame{i}.exr"
                self._set_region(region)
                self.scene.render.filepath = str(tmp)
                bpy.ops.render.render(write_still=True)
                raws.append(read_passes(tmp))
                tmp.unlink(missing_ok=True)
        finally:
            if movers:
                self._clear_motion(plan, movers)
        timings["render"] = time.perf_counter() - t2

        t3 = time.perf_counter()
        out_region = passes_mod.write_frame(out_exr, raws, keys, regions, self.canvas, eff.region.value,
                                            compression=compression)
        timings["write"] = time.perf_counter() - t3

        t4 = time.perf_counter()
        amodal = self._amodal(plan, sorted(kept)) if "index" in outputs else {}
        timings["amodal"] = time.perf_counter() - t4
        self._frames += 1
        timings["total"] = time.perf_counter() - t0
        info.update(region=list(out_region) if out_region else None,
                    regions=[list(self.canvas.region_to_output(r) or r) for r in regions] if regions else None,
                    amodal_px=amodal, skipped=False,
                    timings={k: round(v, 4) for k, v in timings.items()}, rss_mb=round(_rss_mb(), 1))
        return info

    def render_background(self, T_world_cam, lighting: dict | None, out_png: Path, samples: int) -> dict:
        """The twin itself, opaque, under a sky: an 8-bit sRGB PNG (synthetic recordings)."""
        self._check_current()
        t0 = time.perf_counter()
        lighting = lighting or fx.DEFAULT_LIGHTING
        sc = self.scene
        self._hide_objects(True)
        self._set_camera(T_world_cam)
        sc.cycles.seed = noise_seed(out_png.stem)
        self._apply_lighting(lighting, background=True)
        self._set_street_lamps([])  # the twin as itself: the street key lights all of it
        self._set_twin_mode("background", catcher=False)
        if self._ground is not None:
            self._ground.hide_render = False
        if self._catcher is not None:
            self._catcher.hide_render = True
        sc.render.film_transparent = False
        self._set_passes([])
        s = fx.decide_sampling(self.render, ["rgba"]).value
        s["samples"] = int(samples)
        s["adaptive"] = s["adaptive"] and samples >= 16
        self._set_sampling(s)
        self._set_region(None)
        ims = sc.render.image_settings
        t1 = time.perf_counter()
        try:
            ims.media_type = "IMAGE"
            ims.file_format = "PNG"
            ims.color_mode = "RGB"
            ims.color_depth = "8"
            with atomic_path(out_png) as tmp:
                sc.render.filepath = str(tmp)
                bpy.ops.render.render(write_still=True)
            undistort = self.canvas.remapped
        finally:
            ims.media_type = "MULTI_LAYER_IMAGE"
            ims.file_format = "OPEN_EXR_MULTILAYER"
            ims.color_depth = "32"
            sc.render.film_transparent = True
        if undistort:  # the same lens as the real camera: distort the pinhole render
            import cv2

            from blendgen.atomic import write_image
            img = cv2.imread(str(out_png), cv2.IMREAD_COLOR)
            write_image(out_png, self.canvas.to_output(img))
        t2 = time.perf_counter()
        return {"samples": int(samples), "device": self.device,
                "timings": {"scene": round(t1 - t0, 4), "render": round(t2 - t1, 4)},
                "rss_mb": round(_rss_mb(), 1)}

    def close(self):
        if RenderSession._current is self:
            for p in list(self._placed.values()):
                self._remove(p)
            RenderSession._current = None
        self._placed.clear()
        self._tmp_cleanup()
