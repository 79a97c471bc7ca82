"""Sun azimuth from the shadows that real road users cast on the road (bpy-free).

A car or person that the frame analysis found (blendgen/analysis/objects.py: box + ground
footprint) stands on the road; in sunlight its shadow is a dark blob attached to its contact
line. The part of that blob outside the object's box shows which way the shadow falls: its
centroid and the contact point, back-projected onto the ground plane, give the shadow's
ground direction, and the sun's azimuth is the opposite one. This works when the sun is to
the side or in front; when it is behind the camera the caster hides its own shadow, no blob
shows beside it, and the caller falls back (with that reason) to the ephemeris or a default.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from blendgen.ground import to_ground
from blendgen.post.colorspace import LUMA_BGR, srgb_u8_to_linear

CASTERS = ("car", "truck", "bus", "person")  # solid, ground-standing; two-wheelers cast thin shadows
DARK_RATIO = 0.45  # a sun shadow on asphalt is < ~0.45 x the lit road (MIN_SHADOW_RATIO 1.8 -> 0.55)
MIN_BLOB_SHARE = 0.04  # shadow area outside the box, as a share of the box area
MIN_AGREEMENT = 0.7  # length of the mean unit shadow vector: the casters must agree
MIN_BOX_PX = 24


def sun_azimuth_from_shadows(real_bgr: np.ndarray, objects, camera, T_world_cam) -> tuple[float | None, str, list]:
    """(sun azimuth clockwise from north in degrees or None, reason, per-caster details).

    `objects`: RealObject-like items (cls, box [x, y, w, h] in `real_bgr` pixels, footprint);
    `camera`, `T_world_cam`: the camera over the ground plane that the footprints use."""
    casters = [o for o in objects if o.cls in CASTERS and o.footprint is not None
               and min(o.box[2], o.box[3]) >= MIN_BOX_PX]
    if not casters:
        return None, "no real car, truck, bus or person standing on the road to read a shadow from", []
    H, W = real_bgr.shape[:2]
    Y = srgb_u8_to_linear(real_bgr) @ LUMA_BGR
    boxes = np.array([o.box for o in objects], float).reshape(-1, 4)
    vecs, details = [], []
    for o in casters:
        x, y, w, h = o.box
        bottom = y + h
        # Search window: the ground beside and in front of the contact line.
        x0, x1 = int(max(0, x - 1.2 * w)), int(min(W, x + 2.2 * w))
        y0, y1 = int(max(0, bottom - 0.25 * h)), int(min(H, bottom + 0.35 * h))
        if x1 - x0 < 8 or y1 - y0 < 4:
            continue
        win = Y[y0:y1, x0:x1]
        # Every detected object's box, a little past its bottom: dark paint, tyres and the dark
        # under-body (lit from all sides, any sun) say nothing about the sun's direction.
        inside = np.zeros(win.shape, bool)
        for bx, by, bw, bh in boxes:
            inside[max(0, int(by) - y0):max(0, int(by + bh * 1.05) + 1 - y0),
                   max(0, int(bx) - x0):max(0, int(bx + bw) + 1 - x0)] = True
        ground = win[~inside]
        if ground.size < 32:
            continue
        lit = float(np.percentile(ground, 75))
        dark = (win < DARK_RATIO * lit).astype(np.uint8)
        # Keep the dark blobs attached to the contact line (the strip along the box's bottom).
        n, labels = cv2.connectedComponents(dark, connectivity=8)
        c0, c1 = int(x - x0), int(x + w - x0)
        r0, r1 = int(bottom - 0.1 * h - y0), int(bottom + 0.05 * h - y0) + 1
        touching = np.unique(labels[max(0, r0):max(0, r1), max(0, c0):max(0, c1)])
        blob = np.isin(labels, touching[touching > 0]) & ~inside
        area = int(blob.sum())
        det = {"cls": o.cls, "box": [round(float(v), 1) for v in o.box], "shadow_px": area}
        details.append(det)
        if area < MIN_BLOB_SHARE * w * h:
            continue
        vv, uu = np.nonzero(blob)
        g = to_ground(camera, T_world_cam, np.c_[uu + x0, vv + y0])
        g = g[np.isfinite(g).all(axis=1)]
        if not len(g):
            continue
        # Ground centroid of the shadow, each pixel weighted by the ground area it covers
        # (~ range^3 at grazing view: unweighted, the near pixels pull it toward the camera),
        # seen from the footprint's centre.
        wgt = np.linalg.norm(g - np.asarray(T_world_cam)[:2, 3], axis=1) ** 3
        v = (g * wgt[:, None]).sum(axis=0) / wgt.sum() - np.mean(np.asarray(o.footprint, float), axis=0)
        if np.linalg.norm(v) < 1e-3:
            continue
        det["shadow_azimuth_deg"] = round(math.degrees(math.atan2(v[0], v[1])) % 360, 1)
        vecs.append((v / np.linalg.norm(v), area))
    if not vecs:
        return None, (f"none of {len(casters)} real road users shows a shadow beside its contact line "
                      "(sun behind the camera, overcast or shade)"), details
    wsum = sum(a for _, a in vecs)
    mean = sum(u * a for u, a in vecs) / wsum
    agreement = float(np.linalg.norm(mean))
    if agreement < MIN_AGREEMENT:
        return None, (f"the shadows of {len(vecs)} real road users disagree (agreement {agreement:.2f} "
                      f"< {MIN_AGREEMENT})"), details
    shadow_az = math.degrees(math.atan2(mean[0], mean[1]))
    return (shadow_az + 180.0) % 360.0, (f"shadows of {len(vecs)} of {len(casters)} real road users "
                                         f"(agreement {agreement:.2f})"), details
