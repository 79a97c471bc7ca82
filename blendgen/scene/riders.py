"""Riders are people: a ridden bicycle or motorcycle becomes two instances (bpy-free).

COCO, and every detector trained on it, labels the rider as a `person` and the two-wheeler
separately. The planner places a ridden two-wheeler as one track (one footprint for
collisions); `split_rider` turns each planned frame object into the vehicle without its
rider and a `person` (variant `rides` = the vehicle's id, `mount` = the vehicle's variant),
both at the same pose and velocity, each with the tight box of its own geometry.
"""

from __future__ import annotations

import numpy as np

from blendgen.plan import PlacedObject

TWO_WHEELERS = ("bicycle", "motorcycle")


def split_rider(obj: PlacedObject, rider_id: int) -> list[PlacedObject]:
    """[vehicle, rider] for a ridden two-wheeler (ids obj.id and rider_id), else [obj]."""
    v = obj.variant
    if obj.cls not in TWO_WHEELERS or "rider" not in v or v.get("part"):
        return [obj]
    from assets_procedural.shapes import part_box

    lo, hi = part_box(obj.cls, v, "all")
    scale = np.asarray(obj.dims, float) / np.maximum(hi - lo, 1e-9)
    origin = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])
    R = obj.R_world_obj()
    out = []
    for part, oid, cls, variant in (
            ("vehicle", obj.id, obj.cls, {**v, "part": "vehicle"}),
            ("rider", rider_id, "person", {**v["rider"], "kind": "riding", "rides": obj.id,
                                           "mount": {"cls": obj.cls, "variant": v}})):
        plo, phi = part_box(obj.cls, v, part)
        base = np.array([(plo[0] + phi[0]) / 2, (plo[1] + phi[1]) / 2, plo[2]])
        pos = np.asarray(obj.position, float) + R @ ((base - origin) * scale)
        dims = tuple(round(float(x), 4) for x in (phi - plo) * scale)
        if part == "rider":  # the rider's box starts at the pegs: say where the road is under it
            variant["above_ground_m"] = round(float((plo[2] - lo[2]) * scale[2]), 4)
        out.append(PlacedObject(id=oid, cls=cls, position=tuple(float(x) for x in pos), yaw=obj.yaw, dims=dims,
                                variant=variant, velocity=obj.velocity, state=None, scenario=obj.scenario,
                                pitch=obj.pitch, roll=obj.roll))
    return out
