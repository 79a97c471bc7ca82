"""People from MakeHuman's CC0 body (NumPy only): posed by linear blend skinning.

`assets_procedural/data/human.npz` (built by `tools/make_human.py`) holds the body in its
rest A-pose, its skin weights on 15 parts, the joints they turn about, a few fitted garments
(suits split into top and bottom, shoes, hair) and offsets of all of these that shape a man or
a woman of more or less weight (`shape`). A pose is given as target joint
positions (hips, knees, ankles, shoulders, elbows, wrists) plus the torso's forward lean;
each limb part turns by the smallest rotation that carries its rest segment onto the target
one, and every vertex follows its parts' transforms blended by its weights. The body replaced
tubes and ellipsoids that read as mannequins in real photos.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np

from assets_procedural.meshkit import rot_y

DATA = Path(__file__).resolve().parent / "data" / "human.npz"
TOPS_LONG = ("male_casualsuit02", "male_casualsuit03", "male_casualsuit05")  # shirts, jacket
TOPS_SHORT = ("male_casualsuit04", "male_casualsuit06", "female_casualsuit01")  # t-shirts
SKIRT = "female_elegantsuit01"
SHOES = ("shoes01", "shoes05")
HAIR = {"female": ("bob02", "ponytail01", "long01", "short02"), "male": ("short01", "short02", "short03", "short04")}
WEIGHT = {"slim": -0.6, "medium": 0.2, "broad": 0.8}  # MakeHuman's min (-1) .. max (+1) weight


@lru_cache(maxsize=1)
def human() -> dict:
    with np.load(DATA) as z:
        d = {k: z[k] for k in z.files}
    for k in ("parts", "regions", "joint_names", "shapes"):
        d[k] = d[k].tolist()
    return d


def _key(v: dict) -> int:
    return int(v.get("seed", round(float(v.get("height_m", 1.72)) * 1e4)))


def sex(v: dict) -> str:
    """About half the people are women (all who wear a skirt); fixed by the variant's seed so
    that plans stay reproducible without another random draw."""
    return "female" if v.get("skirt") or _key(v) % 20 < 9 else "male"


def outfit(v: dict) -> tuple[str, str, str | None]:
    """(suit, shoes, hair) of a person variant, from its seed like `sex`."""
    k = _key(v) // 20
    suit = SKIRT if v.get("skirt") else (TOPS_LONG if v.get("long_sleeves") else TOPS_SHORT)[k % 3]
    hair = HAIR[sex(v)]
    return suit, SHOES[(k // 3) % len(SHOES)], None if v.get("helmet") else hair[(k // 6) % len(hair)]


def shape(v: dict) -> dict[str, float]:
    """Weights of the shape offsets: the sex, and more or less weight with the build."""
    g, w = sex(v), WEIGHT.get(v.get("build", "medium"), 0.0)
    return {g: 1.0, f"{g}_{'maxweight' if w > 0 else 'minweight'}": abs(w)}


def _shaped(key: str, alpha: dict, idx=None) -> np.ndarray:
    """Array `key` (body_v, joint_pos, <garment>_v) of the shape `alpha`, rows `idx`."""
    d = human()
    sel = slice(None) if idx is None else idx
    x = d[key][sel].astype(float)
    for b, a in alpha.items():
        if a:
            x += a * d[f"{key}@{b}"][sel].astype(float)
    return x


def _align(a, b) -> np.ndarray:
    """The smallest rotation carrying direction `a` onto direction `b`."""
    a = np.asarray(a, float) / np.linalg.norm(a)
    b = np.asarray(b, float) / np.linalg.norm(b)
    c = float(a @ b)
    axis = np.cross(a, b)
    s = float(np.linalg.norm(axis))
    if s < 1e-9:
        return np.eye(3)
    k = axis / s
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + s * K + (1 - c) * K @ K


def rest_scale(v: dict, h: float) -> float:
    """Scale that makes the shaped body `h` metres tall (soles to crown)."""
    d = human()
    return h / float(_shaped("body_v", shape(v), d["body_hull"])[:, 2].max())


def rest_joints(v: dict, h: float) -> dict[str, np.ndarray]:
    """Rest joints of the variant's body, `h` metres tall."""
    J = _shaped("joint_pos", shape(v)) * rest_scale(v, h)
    return dict(zip(human()["joint_names"], J))


def pose_transforms(J: dict, target: dict, lean: float, head_lift: float = 0.0) -> dict:
    """Per part (R, rest anchor, posed anchor) from rest joints `J` and posed joints
    `target` (pelvis, and per side .L/.R: hip, knee, ankle, shoulder, elbow, wrist)."""
    T = {}
    pel = np.asarray(target["pelvis"], float)
    T["pelvis"] = (np.eye(3), J["pelvis"], pel)
    Rt = rot_y(lean)
    T["torso"] = (Rt, J["pelvis"], pel)
    neck = pel + Rt @ (J["neck"] - J["pelvis"])
    T["head"] = (rot_y(lean - head_lift), J["neck"], neck)
    for s in "LR":
        hip = pel + (J["hip." + s] - J["pelvis"])
        knee, ankle = (np.asarray(target[f"{j}.{s}"], float) for j in ("knee", "ankle"))
        T["thigh." + s] = (_align(J["knee." + s] - J["hip." + s], knee - hip), J["hip." + s], hip)
        Rs = _align(J["ankle." + s] - J["knee." + s], ankle - knee)
        T["shin." + s] = (Rs, J["knee." + s], knee)
        T["foot." + s] = (np.eye(3), J["ankle." + s], ankle)
        sh = pel + Rt @ (J["shoulder." + s] - J["pelvis"])
        elbow, wrist = (np.asarray(target[f"{j}.{s}"], float) for j in ("elbow", "wrist"))
        T["upperarm." + s] = (_align(J["elbow." + s] - J["shoulder." + s], elbow - sh), J["shoulder." + s], sh)
        Rf = _align(J["wrist." + s] - J["elbow." + s], wrist - elbow)
        T["forearm." + s] = (Rf, J["elbow." + s], elbow)
        T["hand." + s] = (Rf, J["wrist." + s], wrist)
    return T


def skin(verts: np.ndarray, weights: np.ndarray, T: dict) -> np.ndarray:
    """Linear blend skinning of rest `verts` by per-part transforms `T`."""
    out = np.zeros_like(verts)
    for k, part in enumerate(human()["parts"]):
        w = weights[:, k]
        m = w > 0
        if not m.any():
            continue
        R, a, b = T[part]
        out[m] += w[m, None] * ((verts[m] - a) @ R.T + b)
    return out


def _compact(verts: np.ndarray, faces: np.ndarray):
    used = np.unique(faces[faces >= 0])
    remap = np.full(len(verts), -1, np.int64)
    remap[used] = np.arange(len(used))
    return verts[used], np.where(faces >= 0, remap[np.maximum(faces, 0)], -1)


def _meshes(v: dict):
    """(name, hidden vertices or None) of the body and the variant's garments."""
    d = human()
    suit, shoes, hair = outfit(v)
    hidden = np.zeros(len(d["body_v"]), bool)
    for g in (suit, shoes):
        hidden[d[g + "_hide"]] = True
    return [("body", hidden)] + [(g, None) for g in (suit, shoes, hair) if g]


def posed_meshes(v: dict, h: float, T: dict):
    """[(verts, faces, region)] of the body and its garments posed by `T` (see
    `pose_transforms`), one entry per mesh and region (`human()["regions"]` index), without
    the body faces the garments hide. Faces are (n, 4), -1 padding triangles."""
    d, sc, alpha = human(), rest_scale(v, h), shape(v)
    out = []
    for name, hidden in _meshes(v):
        posed = skin(_shaped(name + "_v", alpha) * sc, d[name + "_w"].astype(float), T)
        faces = d[name + "_f"]
        if hidden is not None:  # the body faces a garment covers
            faces = faces[~np.any(hidden[faces] & (faces >= 0), axis=1)]
        region = d.get(name + "_region", np.zeros(len(posed), np.uint8))
        fr = region[faces[:, 0]]
        for r in np.unique(fr):
            out.append((*_compact(posed, faces[fr == r]), int(r)))
    return out


def posed_bounds(v: dict, h: float, T: dict) -> np.ndarray:
    """The posed vertices that can be extreme (each part's convex hull, `tools/make_human.py`):
    their box is the person's to within a millimetre, at a fifth of the cost of posing all."""
    d, sc, alpha = human(), rest_scale(v, h), shape(v)
    pts = []
    for name, hidden in _meshes(v):
        idx = d[name + "_hull"]
        if hidden is not None:
            idx = idx[~hidden[idx]]
        pts.append(skin(_shaped(name + "_v", alpha, idx) * sc, d[name + "_w"][idx].astype(float), T))
    return np.vstack(pts)
