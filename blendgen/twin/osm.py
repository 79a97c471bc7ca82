"""OpenStreetMap extracts (.osm XML, .osm.pbf) as twins, read with osmium (libosmium).

Roads: `highway=*` ways of motor traffic, with `lanes` / `lanes:forward` / `lanes:backward`,
`oneway`, `width` (else a lane width by road class), `sidewalk`. Nodes shared by two or
more roads become intersections (signal slots where a `highway=traffic_signals` node is
within 20 m); `highway=crossing` nodes become crosswalks; `building=*` ways become
buildings (oriented bounding box of the footprint, `height` or `building:levels`).
Frame: ENU about the centroid of the extract's nodes.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from blendgen.errors import UserError

# lane width (m) and default lanes (forward, backward) of a two-way road, by highway class
ROAD_CLASSES = {
    "motorway": (3.75, 2), "trunk": (3.5, 2), "primary": (3.5, 1), "secondary": (3.25, 1),
    "tertiary": (3.25, 1), "unclassified": (3.0, 1), "residential": (3.0, 1),
    "living_street": (2.75, 1), "service": (2.75, 1),
}
SPEED = {"motorway": 33.3, "trunk": 27.8, "primary": 13.9, "secondary": 13.9, "tertiary": 13.9}
SIDEWALK_M = 2.0
LEVEL_M = 3.0


def _num(v: str | None) -> float | None:
    """A number from an OSM tag value ('3.5', '3.5 m', '4;5' -> first)."""
    if not v:
        return None
    m = re.match(r"\s*([0-9]+(?:\.[0-9]+)?)", v)
    return float(m.group(1)) if m else None


def _road_class(tags) -> str | None:
    hw = tags.get("highway")
    if hw is None:
        return None
    base = hw[:-5] if hw.endswith("_link") else hw
    return base if base in ROAD_CLASSES else None


def twin_data_from_osm(path) -> dict:
    import cv2
    import osmium
    import pymap3d

    path = Path(path)
    nodes, node_tags, ways = {}, {}, []
    try:
        for o in osmium.FileProcessor(str(path)).with_locations():
            if o.is_node():
                if o.location.valid():
                    nodes[o.id] = (o.location.lat, o.location.lon)
                if "highway" in o.tags or "crossing" in o.tags:
                    node_tags[o.id] = dict(o.tags)
            elif o.is_way():
                tags = dict(o.tags)
                if _road_class(tags) or "building" in tags:
                    ways.append((o.id, tags, [n.ref for n in o.nodes]))
    except RuntimeError as e:
        raise UserError(f"cannot read the OSM extract: {e}", where=str(path)) from None
    if not nodes:
        raise UserError("the extract has no nodes with locations", where=str(path))
    ll = np.array(list(nodes.values()))
    lat0, lon0 = float(ll[:, 0].mean()), float(ll[:, 1].mean())
    ids = np.array(list(nodes.keys()))
    e, n, _ = pymap3d.geodetic2enu(ll[:, 0], ll[:, 1], 0.0, lat0, lon0, 0.0)
    xy = dict(zip(ids.tolist(), np.stack([e, n], 1)))

    def pts(refs, wid):
        missing = [r for r in refs if r not in xy]
        if missing:
            raise UserError(f"way {wid} references node {missing[0]} that the extract lacks", where=str(path))
        return np.array([xy[r] for r in refs])

    roads, buildings, use = [], [], {}
    for wid, tags, refs in ways:
        cls = _road_class(tags)
        if cls:
            p = pts(refs, wid)
            if len(p) < 2:
                continue
            lw, per_dir = ROAD_CLASSES[cls]
            oneway = tags.get("oneway", "yes" if tags.get("junction") == "roundabout" or cls == "motorway" else "no")
            if oneway == "-1":
                p, refs = p[::-1], refs[::-1]
            one = oneway in ("yes", "-1", "true", "1")
            lanes = _num(tags.get("lanes"))
            fwd, bwd = _num(tags.get("lanes:forward")), _num(tags.get("lanes:backward"))
            if one:
                fwd, bwd = int(lanes or per_dir), 0
            elif fwd is None or bwd is None:
                total = int(lanes or 2 * per_dir)
                fwd, bwd = max(1, math.ceil(total / 2)), total // 2
            fwd, bwd = int(min(fwd, 6)), int(min(bwd, 6))
            width = _num(tags.get("width"))
            if width:
                lw = width / (fwd + bwd)
            sidewalk = tags.get("sidewalk", "no")
            rid = f"w{wid}"
            roads.append({"id": rid, "points": p.round(3).tolist(), "lanes_forward": fwd, "lanes_backward": bwd,
                          "lane_width_m": float(np.clip(lw, 2.0, 6.0)), "shoulder_m": 0.3,
                          "sidewalk_m": SIDEWALK_M if sidewalk in ("both", "left", "right", "yes") else 0.0,
                          "center_line": "none" if one else ("double" if fwd + bwd >= 4 else "dashed"),
                          "speed_mps": float(np.clip((_num(tags.get("maxspeed")) or 0) / 3.6
                                                     or SPEED.get(cls, 8.3), 1.0, 45.0))})
            for k, r in enumerate(refs):
                use.setdefault(r, []).append((rid, k, p))
        elif "building" in tags and len(refs) >= 4:
            p = pts(refs, wid).astype(np.float32)
            (cx, cy), (w, h), ang = cv2.minAreaRect(p)
            if min(w, h) < 1.0:
                continue
            height = _num(tags.get("height")) or (
                (_num(tags.get("building:levels")) or 3) * LEVEL_M + 1.0)
            levels = _num(tags.get("building:levels"))
            buildings.append({"center": [float(cx), float(cy)], "size": [float(w), float(h)], "yaw_deg": float(ang),
                              "height_m": float(np.clip(height, 2.1, 300.0)),
                              **({"floors": int(np.clip(levels, 1, 80))} if levels else {})})
    if not roads:
        raise UserError("the extract has no roads (highway=* ways of a road class "
                        f"{sorted(ROAD_CLASSES)})", where=str(path))
    signals = [xy[i] for i, t in node_tags.items() if t.get("highway") == "traffic_signals" and i in xy]
    intersections, crosswalks = [], []
    for nid, uses in use.items():
        if len({u[0] for u in uses}) >= 2:
            c = xy[nid]
            sig = any(np.linalg.norm(s - c) < 20.0 for s in signals)
            intersections.append({"id": f"n{nid}", "center": c.round(3).tolist(), "crosswalks": False,
                                  "stop_lines": sig, "signals": sig})
    for nid, t in node_tags.items():
        if (t.get("highway") == "crossing" or "crossing" in t) and nid in use:
            rid, k, p = use[nid][0]
            s = float(np.sum(np.linalg.norm(np.diff(p[:k + 1], axis=0), axis=1))) if k else 0.0
            crosswalks.append({"road": rid, "s_m": round(s, 3), "width_m": 3.0})
    allp = np.vstack([np.asarray(r["points"]) for r in roads])
    return {"name": path.name.split(".")[0], "georef": {"lat0": lat0, "lon0": lon0, "alt0": 0.0},
            "roads": roads, "intersections": intersections, "crosswalks": crosswalks, "buildings": buildings,
            "ground_m": float(np.clip(np.ptp(allp, axis=0).max() + 80.0, 10.0, 20000.0))}
