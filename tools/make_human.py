"""Build assets_procedural/data/human.npz, the skinned body that procedural people are posed
from, out of MakeHuman's CC0 base mesh, skeleton, weights and a few garments:

    git clone https://github.com/makehumancommunity/makehuman /tmp/makehuman
    git clone https://github.com/makehumancommunity/makehuman-assets /tmp/makehuman-assets
    git clone https://github.com/makehumancommunity/mpfb2 /tmp/mpfb2   # the shape targets
    python tools/make_human.py /tmp/makehuman /tmp/makehuman-assets /tmp/mpfb2

Kept: the hm08 body (no helper geometry), its skin weights summed onto the 15 parts a pose
moves (pelvis, torso, head, and per side upper arm, forearm, hand, thigh, shin, foot), the
joints those parts turn about, and garments fitted to the body by their .mhclo (each vertex
from three body vertices plus a scaled offset, its skin weights from the same three), with the
body vertices each garment hides, and shape offsets of all of these for a young adult man
and woman and for more and less weight (MakeHuman's macro targets, as shipped with MPFB 2).
Coordinates in metres, x forward, y left, z up, soles at 0.
Run at build time only; blendgen never downloads it. Textures are not kept (MakeHuman ships
them through Git LFS): garments are coloured per instance by their region.
"""

from __future__ import annotations

import gzip
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import ConvexHull

OUT = Path(__file__).resolve().parents[1] / "assets_procedural" / "data" / "human.npz"
PARTS = ["pelvis", "torso", "head", "upperarm.L", "forearm.L", "hand.L", "upperarm.R", "forearm.R",
         "hand.R", "thigh.L", "shin.L", "foot.L", "thigh.R", "shin.R", "foot.R"]
REGIONS = ["skin", "shirt", "pants", "shoes", "hair"]
# garment -> region (suits are split into tops and bottoms by their connected pieces)
GARMENTS = {
    "clothes/male_casualsuit02": "suit", "clothes/male_casualsuit03": "suit",
    "clothes/male_casualsuit04": "suit", "clothes/male_casualsuit05": "suit",
    "clothes/male_casualsuit06": "suit", "clothes/female_casualsuit01": "suit",
    "clothes/female_elegantsuit01": "suit",
    "clothes/shoes01": "shoes", "clothes/shoes05": "shoes",
    "hair/short01": "hair", "hair/short02": "hair", "hair/short03": "hair", "hair/short04": "hair",
    "hair/bob02": "hair", "hair/ponytail01": "hair", "hair/long01": "hair",
}
# joints a pose needs: name -> (MakeHuman bone, "head" | "tail")
JOINTS = {"pelvis": ("root", "tail"), "neck": ("neck01", "head"), "head": ("head", "head"),
          **{f"{j}.{s}": (b + "." + s, e) for s in "LR" for j, b, e in (
              ("shoulder", "upperarm01", "head"), ("elbow", "lowerarm01", "head"),
              ("wrist", "wrist", "head"), ("hip", "upperleg01", "head"), ("knee", "lowerleg01", "head"),
              ("ankle", "foot", "head"), ("toe", "toe3-1", "head"))}}


def part_of(bone: str) -> str:
    side = bone[-1] if bone[-2:] in (".L", ".R") else ""
    base = bone[:-2] if side else bone
    if base in ("root",):
        return "pelvis"
    if base.startswith(("spine", "breast", "clavicle")):
        return "torso"
    if base.startswith(("shoulder", "upperarm")):
        return "upperarm." + side
    if base.startswith("lowerarm"):
        return "forearm." + side
    if base.startswith(("wrist", "metacarpal", "finger")):
        return "hand." + side
    if base.startswith(("pelvis", "upperleg")):
        return "thigh." + side
    if base.startswith("lowerleg"):
        return "shin." + side
    if base.startswith(("foot", "toe")):
        return "foot." + side
    return "head"  # neck, head, jaw, eyes, tongue and the face's muscles


def to_blender(p: np.ndarray) -> np.ndarray:
    """MakeHuman's decimetres, y up, facing +z, left +x -> metres, x forward, y left, z up."""
    return np.asarray(p, float)[..., [2, 0, 1]] / 10.0


def read_obj(path: Path):
    verts, faces, groups, group = [], [], [], None
    for line in path.read_text().splitlines():
        if line.startswith("v "):
            verts.append([float(x) for x in line.split()[1:4]])
        elif line.startswith("g "):
            group = line.split()[1]
        elif line.startswith("f "):
            faces.append([int(t.split("/")[0]) - 1 for t in line.split()[1:]])
            groups.append(group)
    return np.array(verts), faces, groups


def read_mhclo(path: Path):
    """(refs (N,3), weights (N,3), offsets (N,3), scales (3,) as body-vertex pairs, hidden)."""
    refs, wts, offs, scales, hidden = [], [], [], {}, []
    mode = None
    for line in path.read_text().splitlines():
        line = line.split("#")[0].strip()
        if not line:
            continue
        key = line.split()[0]
        if key in ("x_scale", "y_scale", "z_scale"):
            a, b, d = line.split()[1:]
            scales[key[0]] = (int(a), int(b), float(d))
        elif key == "verts":
            mode = "verts"
        elif key == "delete_verts":
            mode = "delete"
        elif mode == "verts" and re.match(r"^-?\d", key):
            t = line.split()
            if len(t) == 1:  # exactly on one body vertex
                refs.append([int(t[0])] * 3), wts.append([1.0, 0, 0]), offs.append([0.0] * 3)
            else:
                refs.append([int(x) for x in t[:3]]), wts.append([float(x) for x in t[3:6]])
                offs.append([float(x) for x in t[6:9]])
        elif mode == "delete":
            t = line.replace(" - ", "-").split()
            for tok in t:
                a, _, b = tok.partition("-")
                hidden.extend(range(int(a), int(b or a) + 1))
    return np.array(refs), np.array(wts), np.array(offs), scales, np.array(hidden, int)


def bounding_candidates(verts: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Vertices on the convex hull of each part's vertices (by largest weight): a part moves
    rigidly, so its extremes in any direction are among them; the planner sizes people from
    these alone (`body.posed_extent`)."""
    dominant = weights.argmax(1)
    idx = [np.flatnonzero(dominant == k)[ConvexHull(verts[dominant == k]).vertices]
           for k in np.unique(dominant) if (dominant == k).sum() >= 5]
    return np.unique(np.concatenate(idx)).astype(np.int32)


def quads(faces: list[list[int]], remap: np.ndarray | None = None) -> np.ndarray:
    out = np.full((len(faces), 4), -1, np.int32)
    for i, f in enumerate(faces):
        out[i, :len(f)] = f if remap is None else remap[f]
    return out


def read_target(path: Path, n: int) -> np.ndarray:
    """A MakeHuman .target(.gz): per-vertex offsets (index dx dy dz) -> dense (n, 3)."""
    text = (gzip.decompress(path.read_bytes()).decode() if path.suffix == ".gz" else path.read_text())
    d = np.zeros((n, 3))
    rows = [line.split() for line in text.splitlines() if line.strip() and not line.startswith("#")]
    if rows:
        a = np.array(rows, float)
        d[a[:, 0].astype(int)] = a[:, 1:4]
    return d


def shape_bases(targets: Path, n: int) -> dict[str, np.ndarray]:
    """Young adult shapes as offsets from the base mesh: gender from the mean of MakeHuman's
    three ethnic targets (its default mix), weight from the universal min/max targets."""
    out = {}
    for g in ("male", "female"):
        out[g] = np.mean([read_target(targets / f"{e}-{g}-young.target.gz", n)
                          for e in ("african", "asian", "caucasian")], axis=0)
        for w in ("maxweight", "minweight"):
            out[f"{g}_{w}"] = read_target(targets / f"universal-{g}-young-averagemuscle-{w}.target.gz", n)
    return out


def main(makehuman: str, assets: str, mpfb: str) -> None:
    data = Path(makehuman) / "makehuman" / "data"
    base = Path(assets) / "base"
    V, F, G = read_obj(data / "3dobjs" / "base.obj")
    skel = json.loads((data / "rigs" / "default.mhskel").read_text())
    mhw = json.loads((data / "rigs" / "default_weights.mhw").read_text())["weights"]
    W = np.zeros((len(V), len(PARTS)))
    for bone, pairs in mhw.items():
        k = PARTS.index(part_of(bone))
        for vi, w in pairs:
            W[vi, k] += w
    W /= np.maximum(W.sum(1, keepdims=True), 1e-9)

    body_faces = [f for f, g in zip(F, G) if g == "body"]
    used = np.unique(np.concatenate(body_faces))
    remap = np.full(len(V), -1, np.int64)
    remap[used] = np.arange(len(used))
    garments = []
    for rel, kind in GARMENTS.items():
        d = base / rel
        clo = next(d.glob("*.mhclo"))
        obj_file = re.search(r"^obj_file\s+(\S+)", clo.read_text(), re.M).group(1)
        garments.append((d.name, kind, quads(read_obj(d / obj_file)[1]), *read_mhclo(clo)))

    def derive(Vm: np.ndarray) -> dict[str, np.ndarray]:
        """Body, joints and fitted garments of the full base mesh `Vm` (MakeHuman units)."""
        Vb = to_blender(Vm)
        Vb[:, 2] -= Vb[used, 2].min()  # soles at 0
        out = {"joint_pos": np.array([Vb[skel["joints"][skel["bones"][b][e]]].mean(0) for b, e in JOINTS.values()]),
               "body_v": Vb[used]}
        for name, _, _, refs, wts, offs, scales, _ in garments:
            sc = np.array([abs(Vm[scales[a][0], i] - Vm[scales[a][1], i]) / scales[a][2] for i, a in enumerate("xyz")])
            cv = to_blender(np.einsum("nk,nkd->nd", wts, Vm[refs]) + offs * sc)
            out[name + "_v"] = cv - [0, 0, to_blender(Vm)[used, 2].min()]
        return out

    neutral = derive(V)
    out = {"parts": np.array(PARTS), "regions": np.array(REGIONS), "joint_names": np.array(list(JOINTS)),
           "body_f": quads(body_faces, remap), "body_w": W[used].astype(np.float16),
           "body_hull": bounding_candidates(neutral["body_v"], W[used])}
    out.update({k: x.astype(np.float32) for k, x in neutral.items()})
    bases = shape_bases(Path(mpfb) / "src" / "mpfb" / "data" / "targets" / "macrodetails", len(V))
    for b, D in bases.items():  # every derived array is near-linear in the mesh: store offsets
        out.update({f"{k}@{b}": (x - neutral[k]).astype(np.float16) for k, x in derive(V + D).items()})
    out["shapes"] = np.array(list(bases))
    for name, kind, faces, refs, wts, offs, scales, hidden in garments:
        cw = np.einsum("nk,nkp->np", wts, W[refs])
        cw /= np.maximum(cw.sum(1, keepdims=True), 1e-9)
        cv = neutral[name + "_v"]
        region = np.full(len(cv), REGIONS.index(kind if kind != "suit" else "shirt"), np.uint8)
        if kind == "suit":  # a piece whose weights are mostly on the legs is a bottom
            e = np.concatenate([np.stack([f[f >= 0], np.roll(f[f >= 0], 1)], 1) for f in faces])
            n, lab = connected_components(coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])),
                                                     shape=(len(cv),) * 2), directed=False)
            legs = cw[:, [PARTS.index(p) for p in PARTS if p.startswith(("thigh", "shin"))]].sum(1)
            for c in range(n):
                m = lab == c
                if legs[m].mean() > 0.5:
                    region[m] = REGIONS.index("pants")
        hide = np.zeros(len(used), bool)
        hidden = hidden[remap[hidden] >= 0]
        hide[remap[hidden]] = True
        out.update({f"{name}_f": faces, f"{name}_w": cw.astype(np.float16), f"{name}_region": region,
                    f"{name}_hide": np.flatnonzero(hide).astype(np.int32), f"{name}_hull": bounding_candidates(cv, cw)})
        print(f"{name}: {len(cv)} vertices ({len(out[name + '_hull'])} bounding), {len(faces)} faces, "
              f"hides {hide.sum()} body vertices, regions {np.bincount(region, minlength=len(REGIONS)).tolist()}")
    out["garments"] = np.array([g[0] for g in garments])
    out["source"] = np.array([f"makehumancommunity/{r.rstrip('/').split('/')[-1]}@" + subprocess.run(
        ["git", "-C", r, "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()
        for r in (makehuman, assets, mpfb)])
    OUT.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(OUT, **out)
    print(f"wrote {OUT} ({OUT.stat().st_size / 1e6:.2f} MB); body {len(used)} vertices, "
          f"height {neutral['body_v'][:, 2].max():.3f} m; shapes {list(bases)}")


if __name__ == "__main__":
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    main(*sys.argv[1:])
