"""User asset libraries, the bpy-free half (docs/assets.md).

`inject.assets` names folders or files of glTF/GLB, .blend, OBJ, FBX and USD assets. This
module finds them, reads their sidecars (`<stem>.yaml` beside the file, or `asset.yaml` for
the whole folder), checks each file's header and the files it references (buffers,
textures), and turns an asset's measured geometry into its normalised real size and the
transform that puts it in the object frame of `blendgen.plan` (x forward, y left,
z up, origin at the centre of the bottom face). The import and the measuring happen in a
farm worker (`blendgen.render.assets`); its results form the catalog `OUT/assets.json`
that the planner draws from.

Assets as they come from other tools carry what a sidecar would say in their own files:
an OpenMATERIAL 3D `.xoma` beside a glTF states its class, licence and axes (ISO 8855: x
forward, z up); a Gazebo `model.sdf` states a mesh's scale (its unit) and that the model is
Z-up, and names textures as `model://NAME/...`. These fill the sidecar's fields; the job
(`inject.assets: [{path: ..., class: ...}]`) and the sidecars beside the files override them.
"""

from __future__ import annotations

import hashlib
import json
import re
import struct
import xml.etree.ElementTree as ET
from collections import Counter
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Annotated, Literal
from urllib.parse import unquote

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from blendgen import CLASSES
from blendgen.errors import UserError
from blendgen.validation import error_lines, read_yaml_mapping

FORMATS = {".gltf": "gltf", ".glb": "gltf", ".blend": "blend", ".obj": "obj", ".fbx": "fbx",
           ".usd": "usd", ".usda": "usd", ".usdc": "usd", ".usdz": "usd"}
FOLDER_SIDECAR = "asset.yaml"
AXES = ("+x", "-x", "+y", "-y", "+z", "-z")

# Real sizes (length x, width y, height z; metres) an asset of each class may have; the
# catalog's procedural ranges (blendgen/dimensions.py) widened to what real vehicles and
# people span. KEY_DIM is the size a unit-less asset is scaled by.
CLASS_DIMS = {
    "car": ((3.0, 5.6), (1.45, 2.1), (1.2, 2.2)),
    "truck": ((4.8, 18.0), (1.8, 2.6), (1.7, 4.2)),
    "bus": ((7.0, 18.5), (2.2, 2.6), (2.6, 4.4)),
    "person": ((0.15, 1.0), (0.3, 0.9), (1.0, 2.05)),
    "bicycle": ((1.2, 2.0), (0.35, 0.8), (0.8, 2.0)),
    "motorcycle": ((1.5, 2.6), (0.55, 1.1), (0.9, 2.0)),
    "traffic light": ((0.15, 0.6), (0.2, 0.8), (0.3, 1.6)),
}
KEY_DIM = {"person": 2, "traffic light": 2}  # others: length
ABSURD = 2.0  # a size this factor outside the range is an error, not something to rescale
UNITS = (1.0, 0.01, 0.001, 0.0254, 0.1)  # metres per model unit tried for an asset without size


def axis_vector(a: str) -> np.ndarray:
    v = np.zeros(3)
    v["xyz".index(a[1])] = 1.0 if a[0] == "+" else -1.0
    return v


class Sidecar(BaseModel):
    """What the user says about an asset (see docs/assets.md)."""

    model_config = ConfigDict(extra="forbid", populate_by_name=True)

    cls: str = Field(alias="class")
    dims: tuple[Annotated[float, Field(gt=0)], Annotated[float, Field(gt=0)],
                Annotated[float, Field(gt=0)]] | None = None  # real length, width, height (m)
    height_m: Annotated[float, Field(gt=0)] | None = None
    length_m: Annotated[float, Field(gt=0)] | None = None
    front: str | None = None  # axis the asset faces, in Blender's frame after import; None: inferred
    up: str = "+z"            # Blender's importers turn Y-up files (glTF, FBX, OBJ, USD) to Z-up
    variants: list[Annotated[str, Field(min_length=1)]] | None = None  # objects/collections, one asset each
    licence: str | None = None
    mount_height_m: Annotated[float, Field(ge=0, le=10)] = 2.6  # traffic lights: bottom above the road
    unit_m: Annotated[float, Field(gt=0)] | None = None  # metres per model unit (cm: 0.01); None: inferred
    # a texture the file names but that is nowhere near it: stop (error), or render those
    # materials with their base colour (ignore)
    missing_textures: Literal["error", "ignore"] = "error"

    @model_validator(mode="before")
    @classmethod
    def _licence_spelling(cls, d):
        if isinstance(d, dict) and "license" in d and "licence" not in d:
            d = {**d, "licence": d["license"]}
            d.pop("license")
        return d

    @field_validator("cls")
    @classmethod
    def _known(cls, v: str) -> str:
        if v not in CLASSES:
            raise ValueError(f"unknown class {v!r}; expected one of {sorted(CLASSES)}")
        return v

    @field_validator("front", "up")
    @classmethod
    def _axis(cls, v):
        if v is not None and v not in AXES:
            raise ValueError(f"expected an axis, one of {list(AXES)}")
        return v

    @model_validator(mode="after")
    def _consistent(self):
        if self.front is not None and self.front[1] == self.up[1]:
            raise ValueError(f"front {self.front} and up {self.up} are the same axis")
        if sum(x is not None for x in (self.dims, self.height_m, self.length_m, self.unit_m)) > 1:
            raise ValueError("give one of dims, height_m, length_m or unit_m")
        return self


@dataclass
class AssetRef:
    """One asset: a file, or one variant (object/collection) of a file."""

    file: str
    format: str
    variant: str | None
    sidecar: dict          # Sidecar fields (by alias)
    sidecar_file: str | None
    fingerprint: str       # changes when the file or its sidecar does
    notes: list[str] = field(default_factory=list)  # where the sidecar's fields came from

    @property
    def key(self) -> str:
        return self.file + (f"#{self.variant}" if self.variant else "")

    @property
    def spec(self) -> Sidecar:
        return Sidecar.model_validate(self.sidecar)

    def to_dict(self) -> dict:
        return asdict(self)


# ----------------------------------------------------------------------------- discovery

def discover(paths: list) -> list[AssetRef]:
    """Every asset under `paths` (folders are searched recursively), sidecars read and
    headers checked; UserError naming the first bad file. An item is a path or (path, sidecar
    fields given in the job)."""
    refs: list[AssetRef] = []
    for item in paths:
        p, given = (item if isinstance(item, tuple) else (item, {}))
        p = Path(p)
        if not p.exists():
            raise UserError("asset path does not exist", where=f"inject.assets: {p}")
        if p.is_file():
            if p.suffix.lower() not in FORMATS:
                raise UserError(f"unsupported asset format {p.suffix!r}; expected one of "
                                f"{sorted(FORMATS)}", where=str(p))
            files = [p]
        else:
            files = sorted(f for f in p.rglob("*") if f.is_file() and f.suffix.lower() in FORMATS
                           and not any(part.startswith(".") for part in f.relative_to(p).parts))
            if not files:
                raise UserError(f"no assets in this folder (expected files ending in {sorted(FORMATS)})",
                                where=f"inject.assets: {p}")
        for f in files:
            refs.extend(asset_refs(f.resolve(), given))
    dup = [k for k, n in Counter(r.key for r in refs).items() if n > 1]
    if dup:
        raise UserError("asset listed twice in inject.assets", where=dup[0])
    return refs


def read_sidecar(file: Path, given: dict | None = None) -> tuple[Sidecar, str | None, list[str]]:
    """The file's sidecar: what the file's own metadata says (OpenMATERIAL .xoma, Gazebo
    model.sdf), then the folder's `asset.yaml`, the file's `<stem>.yaml` and the fields given in
    the job, each overriding the one before key by key. Returns (sidecar, the last sidecar file
    read, notes on where fields came from)."""
    data, notes = metadata_fields(file)
    user: dict = {}  # what the sidecars and the job say
    used = []
    for sc in (file.parent / FOLDER_SIDECAR, file.with_suffix(".yaml")):
        if sc.is_file() and sc != file:
            d = read_yaml_mapping(sc, "asset sidecar")
            if not isinstance(d, dict):
                raise UserError(f"expected a mapping of sidecar fields (class, dims, front, up, variants, "
                                f"licence), got {type(d).__name__}", where=str(sc))
            user.update(_licence_spelling(d))
            used.append(sc)
    if given:
        user.update(_licence_spelling(given))
        notes.append(f"from the job: {', '.join(sorted(given))}")
    if any(k in user for k in ("dims", "height_m", "length_m")):
        data.pop("unit_m", None)  # a size the user states wins over the metadata's unit
    data.update(user)
    if "class" not in data:
        raise UserError(f"no sidecar: write {file.with_suffix('.yaml').name} (or {FOLDER_SIDECAR} for the "
                        f"folder) with at least `class:`, one of {sorted(CLASSES)}, or give it in the job "
                        f"(inject.assets: [{{path: {file.name}, class: car}}]); blendgen does not guess "
                        f"an asset's class", where=str(file))
    try:
        spec = Sidecar.model_validate(data)
    except ValidationError as e:
        where = " + ".join(map(str, used + (["inject.assets"] if given else []))) or str(file)
        raise UserError("bad asset sidecar:\n  " + "\n  ".join(error_lines(e, " (see docs/assets.md)")),
                        where=where) from None
    check_given_size(spec, where=str(used[-1]) if used else str(file))
    return spec, (str(used[-1]) if used else None), notes


def _licence_spelling(d: dict) -> dict:
    return {("licence" if k == "license" else k): v for k, v in d.items()}


def asset_refs(file: Path, given: dict | None = None) -> list[AssetRef]:
    fmt = FORMATS[file.suffix.lower()]
    spec, sc_file, notes = read_sidecar(file, given)
    check_file(file, fmt, missing_textures=spec.missing_textures)
    sidecar = spec.model_dump(by_alias=True)
    st = file.stat()  # like make: a changed file (size or time) or sidecar is inspected again
    fp = hashlib.sha256(json.dumps([str(file), st.st_size, st.st_mtime_ns, sidecar],
                                   sort_keys=True).encode()).hexdigest()[:16]
    return [AssetRef(str(file), fmt, v, sidecar, sc_file, fp, notes) for v in (spec.variants or [None])]


# ----------------------------------------------------------------------------- other tools' metadata

# OpenMATERIAL 3D's objectClass / vehicleCategory -> our classes (asset_schema.json v1.x)
XOMA_CLASSES = {"human": "person", "car": "car", "van": "car", "truck": "truck", "semitrailer": "truck",
                "trailer": "truck", "bus": "bus", "motorbike": "motorcycle", "motorcycle": "motorcycle",
                "bicycle": "bicycle", "trafficLight": "traffic light", "traffic_light": "traffic light"}


def metadata_fields(file: Path) -> tuple[dict, list[str]]:
    """Sidecar fields stated by the file's own metadata, and notes saying which file said them."""
    data, notes = {}, []
    xoma = file.with_suffix(".xoma")
    if file.suffix.lower() in (".gltf", ".glb") and xoma.is_file():
        try:
            meta = json.loads(xoma.read_text(errors="replace")).get("metadata") or {}
        except (json.JSONDecodeError, AttributeError):
            meta = {}
        cat = (meta.get("vehicleClassData") or {}).get("vehicleCategory") if meta.get("objectClass") == "vehicle" \
            else meta.get("objectClass")
        if cat in XOMA_CLASSES:
            data["class"] = XOMA_CLASSES[cat]
        if meta.get("license"):
            data["licence"] = str(meta["license"])
        # OpenMATERIAL assets use ISO 8855 axes (x forward, y left, z up), which Blender's glTF
        # import keeps
        data.update(front="+x", up="+z")
        notes.append(f"{xoma.name}: " + ", ".join(f"{k} {v}" for k, v in data.items()))
    sdf = _gazebo_sdf(file)
    if sdf is not None:
        sdf_path, scale = sdf
        if scale is not None:
            data["unit_m"] = scale
        if file.suffix.lower() == ".obj":
            # Gazebo models are Z-up; Blender's OBJ import takes the file as Y-up (file z -> -y)
            data["up"] = "-y"
        lic = _licence_line(sdf_path.parent)
        if lic:
            data["licence"] = lic
        notes.append(f"{sdf_path}: " + ", ".join(f"{k} {v}" for k, v in data.items() if k != "licence"))
    return data, notes


def _gazebo_sdf(file: Path) -> tuple[Path, float | None] | None:
    """(model.sdf, the mesh's uniform scale) when `file` is a mesh a Gazebo model's SDF names."""
    for model in list(file.parents)[:3]:
        sdf = model / "model.sdf"
        if not sdf.is_file():
            continue
        try:
            root = ET.parse(sdf).getroot()
        except (ET.ParseError, OSError):
            return None
        for mesh in root.iter("mesh"):
            uri = (mesh.findtext("uri") or "").strip()
            target = resolve_reference(uri, sdf.parent) if uri else None
            if target is None or target.resolve() != file.resolve():
                continue
            text = (mesh.findtext("scale") or "").split()
            try:
                vals = [float(v) for v in text]
            except ValueError:
                vals = []
            scale = vals[0] if vals and max(vals) - min(vals) < 1e-9 * max(1.0, abs(vals[0])) and vals[0] > 0 else None
            return sdf, scale
        return None
    return None


def _licence_line(folder: Path) -> str | None:
    """The first line of the nearest LICENSE file at or above a model's folder (2 levels)."""
    for d in [folder, *list(folder.parents)[:2]]:
        for name in ("LICENSE", "LICENSE.txt", "LICENCE", "COPYING"):
            f = d / name
            if f.is_file():
                line = next((ln.strip() for ln in f.read_text(errors="replace").splitlines() if ln.strip()), "")
                return f"{line[:120]} ({f})" if line else str(f)
    return None


def resolve_reference(ref: str, base: Path) -> Path | None:
    """The file a model names as `ref` relative to `base`: the path as written, a Gazebo
    `model://NAME/...` URI (NAME a folder beside or above the model), else the file's name in
    the usual texture folders (textures/, ../textures, ../materials/textures), ignoring case."""
    ref = unquote(ref.strip().strip('"')).replace("\\", "/")
    cands = []
    if ref.startswith("model://"):
        rest = ref[len("model://"):]
        cands += [d / rest for d in [base, *list(base.parents)[:4]]]
    elif ref:
        cands.append(base / ref)
    name = Path(ref).name
    dirs = [base, base / "textures", base.parent / "textures", base.parent / "materials" / "textures",
            base / "materials" / "textures"]
    cands += [d / name for d in dirs] if name else []
    for c in cands:
        if c.is_file():
            return c
    low = name.lower()
    for d in dirs:
        if low and d.is_dir():
            hit = next((f for f in d.iterdir() if f.name.lower() == low and f.is_file()), None)
            if hit is not None:
                return hit
    return None


# ----------------------------------------------------------------------------- headers

def check_file(file: Path, fmt: str, missing_textures: str = "error") -> None:
    """Read the file's header (glTF and OBJ: the whole text) and the files it references,
    without Blender. A texture is found where the file says, or where `resolve_reference`
    looks; one found nowhere is an error unless `missing_textures` is "ignore"."""
    try:
        with open(file, "rb") as f:
            data = f.read() if fmt in ("gltf", "obj") else f.read(8192)
    except OSError as e:
        raise UserError(f"cannot read the asset file ({e.strerror})", where=str(file)) from None
    if not data:
        raise UserError("the asset file is empty", where=str(file))
    if fmt in ("gltf", "obj"):
        {"gltf": _check_gltf, "obj": _check_obj}[fmt](file, data, missing_textures == "ignore")
    else:
        {"blend": _check_blend, "fbx": _check_fbx, "usd": _check_usd}[fmt](file, data)


MISSING_HINT = ("put it there, or write `missing_textures: ignore` in the sidecar (or the job's entry) to render "
                "its materials with their base colour")


def _check_gltf(file: Path, data: bytes, ignore_textures: bool = False) -> None:
    if file.suffix.lower() == ".glb":
        if data[:4] != b"glTF":
            raise UserError("not a GLB file (the first 4 bytes are not 'glTF')", where=str(file))
        if len(data) < 20:
            raise UserError("GLB file truncated (shorter than its 20-byte header)", where=str(file))
        version, length = struct.unpack_from("<II", data, 4)
        if version != 2:
            raise UserError(f"GLB version {version}; Blender's importer reads glTF 2", where=str(file))
        if length != len(data):
            raise UserError(f"GLB file truncated or padded: header says {length} bytes, file has {len(data)}",
                            where=str(file))
        n, kind = struct.unpack_from("<II", data, 12)
        if kind != 0x4E4F534A:
            raise UserError("GLB's first chunk is not JSON", where=str(file))
        text = data[20:20 + n]
    else:
        text = data
    try:
        doc = json.loads(text)
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise UserError(f"glTF JSON does not parse: {e}", where=str(file)) from None
    if not isinstance(doc, dict) or not str((doc.get("asset") or {}).get("version", "")).startswith("2"):
        raise UserError("not a glTF 2 document (no asset.version 2.x)", where=str(file))
    if not doc.get("meshes"):
        raise UserError("no geometry: the glTF has no meshes", where=str(file))
    for i, item in enumerate(doc.get("buffers") or []):
        uri = item.get("uri")
        if uri and not uri.startswith("data:") and not (file.parent / unquote(uri)).is_file():
            raise UserError(f"missing buffer file {uri!r} (buffers[{i}]; looked in {file.parent})", where=str(file))
    for i, item in enumerate(doc.get("images") or []):
        uri = item.get("uri")
        if uri and not uri.startswith("data:") and resolve_reference(uri, file.parent) is None and not ignore_textures:
            raise UserError(f"missing texture file {uri!r} (images[{i}]; looked in {file.parent}, its textures/ "
                            f"and ../materials/textures): {MISSING_HINT}", where=str(file))


def _check_blend(file: Path, data: bytes) -> None:
    if data[:7] == b"BLENDER":
        return
    if data[:4] == b"\x28\xb5\x2f\xfd" or data[:2] == b"\x1f\x8b":  # zstd / gzip-compressed .blend
        return
    raise UserError("not a .blend file (no 'BLENDER' header, not a compressed .blend)", where=str(file))


_MAP = re.compile(r"^\s*(map_\w+|bump|disp|norm|refl)\s+(.+?)\s*$", re.M)


def _check_obj(file: Path, data: bytes, ignore_textures: bool = False) -> None:
    text = data.decode("utf-8", "replace")
    if "\x00" in text[:4096]:
        raise UserError("not an OBJ file (binary data; OBJ is text)", where=str(file))
    if not re.search(r"^v\s", text, re.M) or not re.search(r"^f\s", text, re.M):
        raise UserError("no geometry: the OBJ has no vertices ('v') or no faces ('f')", where=str(file))
    for lib in re.findall(r"^mtllib\s+(.+?)\s*$", text, re.M):
        mtl = file.parent / lib
        if not mtl.is_file():
            raise UserError(f"missing material library {lib!r} (looked in {file.parent})", where=str(file))
        for _, arg in _MAP.findall(mtl.read_text(errors="replace")):
            tex = arg.split()[-1]  # options (-bm 1 ...) come before the file name
            if resolve_reference(tex, mtl.parent) is None and not ignore_textures:
                raise UserError(f"missing texture {tex!r} (named in {mtl.name}; looked in {mtl.parent}, its "
                                f"textures/ and ../materials/textures): {MISSING_HINT}", where=str(file))


def _check_fbx(file: Path, data: bytes) -> None:
    if data.startswith(b"Kaydara FBX Binary  \x00"):
        return
    if b"FBXHeaderExtension" in data[:8192]:
        raise UserError("ASCII FBX: Blender's importer reads binary FBX only; re-export as binary",
                        where=str(file))
    raise UserError("not an FBX file (no 'Kaydara FBX Binary' header)", where=str(file))


def _check_usd(file: Path, data: bytes) -> None:
    ext = file.suffix.lower()
    ok = {".usda": (b"#usda",), ".usdc": (b"PXR-USDC",), ".usdz": (b"PK\x03\x04",),
          ".usd": (b"#usda", b"PXR-USDC")}[ext]
    if not data.startswith(ok):
        raise UserError(f"not a {ext} file (expected it to start with {' or '.join(map(repr, ok))})",
                        where=str(file))


# ----------------------------------------------------------------------------- sizes

def _range_text(cls: str, i: int) -> str:
    lo, hi = CLASS_DIMS[cls][i]
    return f"{lo:g}-{hi:g} m"


def check_given_size(spec: Sidecar, where: str) -> None:
    """A size the sidecar states must be a real size of its class (within ABSURD of the range)."""
    given = ([(i, v) for i, v in enumerate(spec.dims)] if spec.dims else
             [(2, spec.height_m)] if spec.height_m else [(0, spec.length_m)] if spec.length_m else [])
    names = ("length", "width", "height")
    for i, v in given:
        lo, hi = CLASS_DIMS[spec.cls][i]
        if not lo / ABSURD <= v <= hi * ABSURD:
            raise UserError(f"absurd size: {names[i]} {v:g} m for a {spec.cls} (real ones: {_range_text(spec.cls, i)})",
                            where=where)


def infer_front(cls: str, raw_dims: np.ndarray, up: str) -> str:
    """The axis an asset faces when the sidecar does not say: vehicles face along their long
    horizontal axis; the sign follows glTF's and Blender's convention (models face -y after
    import, i.e. glTF +z), else +x."""
    horiz = [a for a in "xyz" if a != up[1]]
    sizes = {a: raw_dims["xyz".index(a)] for a in horiz}
    if cls in ("person", "traffic light"):  # the thin horizontal axis is the depth
        a = min(sizes, key=sizes.get) if abs(sizes[horiz[0]] - sizes[horiz[1]]) > 1e-6 else "y"
    else:
        a = max(sizes, key=sizes.get)
    return ("-" if a == "y" else "+") + a


def normalisation(spec: Sidecar, lo: np.ndarray, hi: np.ndarray, where: str, front: str | None = None,
                  front_source: str | None = None) -> dict:
    """From the asset's bounds in Blender's frame after import to the object frame.

    ``front``: the axis found from the geometry (blendgen.render.assets: the tail lamps) when
    the sidecar does not say, ``front_source`` how. Returns {"transform": 4x4 (rotation to x
    forward / z up, uniform scale, bottom centre to the origin), "dims": normalised (L, W, H),
    "scale", "raw_dims", "front", "up", "front_inferred", "front_source"}; UserError for no
    geometry or an absurd size or proportion, naming the axes and unit that would fit."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    raw = hi - lo
    if not np.all(np.isfinite(raw)) or raw.max() <= 0:
        raise UserError("no geometry: the asset's meshes have no extent", where=where)
    if spec.front is not None:
        front, source = spec.front, "stated"
    elif front is not None and front[1] != spec.up[1]:
        source = front_source or "geometry"
    else:
        front, source = infer_front(spec.cls, raw, spec.up), "longest axis" if spec.cls not in KEY_DIM else "thinnest axis"
    dims0 = _turned_dims(raw, front, spec.up)
    if np.any(dims0 <= 1e-9):
        raise UserError(f"no geometry: the asset is flat ({dims0[0]:.3g} x {dims0[1]:.3g} x {dims0[2]:.3g})",
                        where=where)
    cls = spec.cls
    scale = _scale(spec, dims0)
    dims = dims0 * scale
    names = ("length", "width", "height")
    for i in range(3):
        a, b = CLASS_DIMS[cls][i]
        if not a / ABSURD <= dims[i] <= b * ABSURD:
            raise UserError(f"absurd size: scaled to real size it is {dims[0]:.2f} x {dims[1]:.2f} x {dims[2]:.2f} m "
                            f"(L x W x H; front {front}, up {spec.up}, {scale:g} m per unit); a {cls}'s {names[i]} is "
                            f"{_range_text(cls, i)}. {_what_fits(spec, raw)}", where=where)
    R = _rotation(front, spec.up)
    # R is an axis permutation with signs, so the turned box of the bounds is exact.
    c = np.array(_corners(lo, hi)) @ (scale * R).T
    a, b = c.min(axis=0), c.max(axis=0)
    T = np.eye(4)
    T[:3, :3] = scale * R
    T[:3, 3] = [-(a[0] + b[0]) / 2, -(a[1] + b[1]) / 2, -a[2]]
    return {"transform": T.round(9).tolist(), "dims": [round(float(x), 4) for x in dims], "scale": scale,
            "raw_dims": [round(float(x), 6) for x in raw], "front": front, "up": spec.up,
            "front_inferred": source not in ("stated",), "front_source": source}


def _rotation(front: str, up: str) -> np.ndarray:
    fx, uz = axis_vector(front), axis_vector(up)
    return np.stack([fx, np.cross(uz, fx), uz])  # rows: the object axes in the import frame


def _turned_dims(raw: np.ndarray, front: str, up: str) -> np.ndarray:
    return np.abs(_rotation(front, up)) @ raw  # (L, W, H) before scaling


def _scale(spec: Sidecar, dims0: np.ndarray) -> float:
    cls = spec.cls
    k = KEY_DIM.get(cls, 0)
    lo_k, hi_k = CLASS_DIMS[cls][k]
    if spec.dims is not None:
        # uniform scale: the geometric mean of the three ratios; proportions are the asset's
        return float(np.exp(np.mean(np.log(np.asarray(spec.dims) / dims0))))
    if spec.height_m is not None:
        return spec.height_m / dims0[2]
    if spec.length_m is not None:
        return spec.length_m / dims0[0]
    if spec.unit_m is not None:
        return spec.unit_m
    # no stated size: a unit that makes it real (m, cm, mm, inch, dm), else the nearest real size
    scale = next((u for u in UNITS if lo_k <= dims0[k] * u <= hi_k), None)
    return scale or float(np.clip(dims0[k], lo_k, hi_k) / dims0[k])


def _what_fits(spec: Sidecar, raw: np.ndarray) -> str:
    """What to write in the sidecar for an asset whose size came out absurd: the up axis and
    unit (of the usual ones) under which all three sizes are real for its class."""
    fits = []
    for up in AXES:
        horiz = [a for a in "xyz" if a != up[1]]
        for h in horiz:
            front = ("-" if h == "y" else "+") + h
            dims0 = _turned_dims(raw, front, up)
            for u in UNITS:
                d = dims0 * u
                # ranges widened by a quarter: mirrors, a roof rack
                if all(CLASS_DIMS[spec.cls][i][0] / 1.25 <= d[i] <= CLASS_DIMS[spec.cls][i][1] * 1.25 for i in range(3)):
                    fits.append((up, front, u, d))
    if not fits:
        return "No axes and unit (m, cm, mm, inch, dm) make it one: check the class and the model"
    # the stated up axis first, then the stated unit
    fits.sort(key=lambda f: (f[0][1] != spec.up[1], spec.unit_m is not None and f[2] != spec.unit_m))
    up, front, u, d = fits[0]
    unit = {1.0: "m", 0.01: "cm", 0.001: "mm", 0.0254: "inch", 0.1: "dm"}[u]
    return (f"With up along {up[1]} (`up: +{up[1]}` or `up: -{up[1]}`, whichever points to its roof), front "
            f"along {front[1]} and `unit_m: {u:g}` ({unit}) it is {d[0]:.2f} x {d[1]:.2f} x {d[2]:.2f} m: write "
            f"those in the sidecar (or the job's entry)")


def _corners(lo, hi):
    return [(x, y, z) for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]


# ----------------------------------------------------------------------------- catalog

CATALOG_NAME = "assets.json"


def asset_variant(entry: dict) -> dict:
    """The PlacedObject variant that makes the render worker build this library asset."""
    v = {"asset": entry["key"], "file": entry["file"], "format": entry["format"], "node": entry["variant"],
         "transform": entry["transform"], "fingerprint": entry["fingerprint"],
         "kind": "standing" if entry["cls"] == "person" else "asset"}  # a library person keeps its pose
    if entry["cls"] == "traffic light":
        v["mount_height_m"] = entry["mount_height_m"]
    return v


class AssetSampler:
    """Draws library assets for the planner: for a class the library has, a share
    `asset_share` (one for all classes, or per class) of the objects come from the library
    (uniformly over its assets)."""

    def __init__(self, catalog: list[dict], share: float | dict[str, float]):
        # per class ({car: 1, bus: 0}; a class not named takes 1), or one share for all
        self.share = {c: float(share.get(c, 1.0)) for c in CLASSES} if isinstance(share, dict) else \
            dict.fromkeys(CLASSES, float(share))
        self.by_cls: dict[str, list[dict]] = {}
        for e in catalog:
            self.by_cls.setdefault(e["cls"], []).append(e)

    def draw(self, cls: str, rng: np.random.Generator) -> tuple[dict, tuple] | None:
        entries = self.by_cls.get(cls)
        if not entries or self.share[cls] <= 0 or rng.random() >= self.share[cls]:
            return None
        e = entries[int(rng.integers(len(entries)))]
        return asset_variant(e), tuple(float(x) for x in e["dims"])


def result_path(state_dir: Path, ref: AssetRef) -> Path:
    """Where the inspection result of one asset goes (resumable: keyed by its fingerprint)."""
    tag = f"_{ref.variant}" if ref.variant else ""
    safe = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in tag)
    return Path(state_dir) / "assets" / f"{ref.fingerprint}{safe}.json"
