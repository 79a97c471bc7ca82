"""Plain bpy primitives: the ground plane for footage without a twin, and box objects.

`box_object` builds a PlacedObject as a coloured box of its dims; it follows the same
contract as `assets_procedural.objects.build_object` (root object, pass_index = id) and
serves tests and benchmarks that must not depend on the procedural asset library.
"""

from __future__ import annotations

import warnings

import bpy
import numpy as np


def material(name: str, color, roughness: float = 0.5, metallic: float = 0.0) -> bpy.types.Material:
    mat = bpy.data.materials.new(name)
    with warnings.catch_warnings():  # deprecated in 5.0 but still needed for a new material
        warnings.simplefilter("ignore", DeprecationWarning)
        mat.use_nodes = True
    bsdf = mat.node_tree.nodes.get("Principled BSDF")
    bsdf.inputs["Base Color"].default_value = (*color[:3], 1.0)
    bsdf.inputs["Roughness"].default_value = roughness
    bsdf.inputs["Metallic"].default_value = metallic
    mat.diffuse_color = (*color[:3], 1.0)
    return mat


def box_mesh(name: str, size, origin_bottom: bool = True) -> bpy.types.Mesh:
    """A box of size (x, y, z) centred in x and y, bottom face at z = 0 (or centred)."""
    sx, sy, sz = (float(s) / 2 for s in size)
    z0, z1 = (0.0, 2 * sz) if origin_bottom else (-sz, sz)
    v = [(-sx, -sy, z0), (sx, -sy, z0), (sx, sy, z0), (-sx, sy, z0),
         (-sx, -sy, z1), (sx, -sy, z1), (sx, sy, z1), (-sx, sy, z1)]
    f = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]
    me = bpy.data.meshes.new(name)
    me.from_pydata(v, [], f)
    me.update()
    return me


def plane_mesh(name: str, size_x: float, size_y: float) -> bpy.types.Mesh:
    sx, sy = size_x / 2, size_y / 2
    me = bpy.data.meshes.new(name)
    me.from_pydata([(-sx, -sy, 0), (sx, -sy, 0), (sx, sy, 0), (-sx, sy, 0)], [], [(0, 1, 2, 3)])
    me.update()
    return me


def add_object(name: str, data, collection=None, role: str | None = None) -> bpy.types.Object:
    ob = bpy.data.objects.new(name, data)
    (collection or bpy.context.scene.collection).objects.link(ob)
    if role is not None:
        ob["blendgen_role"] = role
    return ob


def ground_plane(size_m: float = 400.0, color=(0.25, 0.25, 0.25)) -> bpy.types.Object:
    """A flat road at z = 0 (world frame of a ground-plane twin), role 'road'."""
    ob = add_object("ground_plane", plane_mesh("ground_plane", size_m, size_m), role="road")
    ob.data.materials.append(material("ground_plane", color, roughness=0.9))
    return ob


def box_object(obj) -> bpy.types.Object:
    """A PlacedObject as a box of its dims: origin at the bottom-face centre, pass_index = id."""
    rng = np.random.default_rng(int(obj.variant.get("seed", obj.id)) if obj.variant else int(obj.id))
    color = obj.variant.get("color") if obj.variant else None
    color = color or tuple(float(c) for c in rng.uniform(0.1, 0.8, 3))
    ob = add_object(f"obj{obj.id}", box_mesh(f"obj{obj.id}", obj.dims))
    ob.data.materials.append(material(f"obj{obj.id}", color, roughness=0.4))
    ob.pass_index = int(obj.id)
    ob.location = tuple(float(c) for c in obj.position)
    ob.rotation_euler = obj.euler_xyz  # yaw, and the road's pitch/roll
    return ob
