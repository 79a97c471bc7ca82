"""Multilayer EXR passes: read Blender's render EXR (and write the same layout), bpy-free.

Blender 5 writes one part per pass ("ViewLayer.Combined", "ViewLayer.Object Index", ...);
our own writer (used after the distortion remap and for empty frames) writes one part
with the same channel names. Both read back through `read_passes` as full-frame arrays.
"""

from __future__ import annotations

import functools
import os
from pathlib import Path

import numpy as np

from blendgen.atomic import atomic_path
from blendgen.errors import UserError

# Blender pass name -> our key. "Noisy ..." passes (kept by the denoiser) are ignored.
PASS_KEYS = {
    "Combined": "rgba",
    "Object Index": "index",
    "IndexOB": "index",
    "Depth": "depth",
    "Shadow Catcher": "shadow_catcher",
    "Diffuse Direct": "diffuse_direct",
    "Diffuse Indirect": "diffuse_indirect",
    "Diffuse Color": "diffuse_color",
    "Glossy Direct": "glossy_direct",
    "Glossy Indirect": "glossy_indirect",
    "Glossy Color": "glossy_color",
}
KEY_PASSES = {v: k for k, v in PASS_KEYS.items() if k != "IndexOB"}
LIGHTING_KEYS = ("diffuse_direct", "diffuse_indirect", "diffuse_color",
                 "glossy_direct", "glossy_indirect", "glossy_color")
# Lossless codecs write_passes offers (name -> OpenEXR constant).
COMPRESSIONS = {"zip": "ZIP_COMPRESSION", "zips": "ZIPS_COMPRESSION", "rle": "RLE_COMPRESSION",
                "piz": "PIZ_COMPRESSION", "none": "NO_COMPRESSION"}


@functools.cache
def _openexr():
    """OpenEXR with its thread pool on: the Python module leaves it off (0 threads), so ZIP
    blocks were compressed one after another; on a 16-core GPU host writing the frame's EXR
    was then half its wall time (docs/render.md, GPU)."""
    import OpenEXR

    OpenEXR.set_global_thread_count(len(os.sched_getaffinity(0)))
    return OpenEXR


# Blender writes 1e10 for "no hit" in Depth; we store 0 there so every pass stays finite.
NO_HIT_DEPTH = 1e9


def _split(name: str) -> tuple[str, str]:
    """'ViewLayer.Object Index.X' -> ('Object Index', 'X'); 'ViewLayer.Combined' -> ('Combined', '')."""
    parts = name.split(".")
    if len(parts) >= 3:
        return parts[1], ".".join(parts[2:])
    if len(parts) == 2:
        return (parts[1], "") if parts[1] in PASS_KEYS else (parts[0], parts[1])
    return parts[0], ""


def _full_frame(arr: np.ndarray, header: dict, fill: float = 0.0) -> np.ndarray:
    """Pad a data-window array into the display window (`fill` outside)."""
    dw, disp = header.get("dataWindow"), header.get("displayWindow")
    if dw is None or disp is None:
        return arr
    (dx0, dy0), (dx1, dy1) = np.asarray(dw[0]), np.asarray(dw[1])
    (px0, py0), (px1, py1) = np.asarray(disp[0]), np.asarray(disp[1])
    W, H = int(px1 - px0 + 1), int(py1 - py0 + 1)
    if arr.shape[:2] == (H, W) and (dx0, dy0) == (px0, py0):
        return arr
    out = np.full((H, W) + arr.shape[2:], fill, dtype=arr.dtype)
    x0, y0 = int(dx0 - px0), int(dy0 - py0)
    xs0, ys0 = max(0, -x0), max(0, -y0)
    xe, ye = min(W, x0 + arr.shape[1]), min(H, y0 + arr.shape[0])
    out[max(0, y0):ye, max(0, x0):xe] = arr[ys0:ys0 + ye - max(0, y0), xs0:xs0 + xe - max(0, x0)]
    return out


def read_passes(path: str | Path) -> dict[str, np.ndarray]:
    """Read a render EXR into {key: array}; keys as in docs/architecture.md, only those present.

    rgba (H,W,4) float32 linear premultiplied; index (H,W) int32 (0 = background);
    depth (H,W) float32 metres along the optical axis (0 = no hit); the rest (H,W,3) float32.
    Full frame: outside a file's data window every pass is 0, except shadow_catcher (1).
    """
    OpenEXR = _openexr()

    path = Path(path)
    if not path.is_file():
        raise UserError("render EXR not found (was the frame rendered?)", where=str(path))
    try:
        f = OpenEXR.File(str(path))
        parts = list(f.parts)
    except Exception as e:  # OpenEXR raises plain exceptions for truncated/corrupt files
        raise UserError(f"cannot read EXR ({e}); expected a multilayer OpenEXR written by the render stage",
                        where=str(path)) from None
    out: dict[str, np.ndarray] = {}
    for part in parts:
        header = part.header
        for name, ch in part.channels.items():
            pass_name, _sub = _split(name)
            key = PASS_KEYS.get(pass_name)
            if key is None or key in out:
                continue
            try:
                arr = np.asarray(ch.pixels)
            except Exception as e:
                raise UserError(f"cannot decode channel {name!r} ({e})", where=str(path)) from None
            # Outside the rendered window: nothing there, so no shadow (catcher factor 1).
            arr = _full_frame(arr, header, 1.0 if key == "shadow_catcher" else 0.0)
            if key == "index":
                arr = np.rint(arr.reshape(arr.shape[:2])).astype(np.int32)
            elif key == "depth":
                arr = arr.reshape(arr.shape[:2]).astype(np.float32)
                arr = np.where((arr >= NO_HIT_DEPTH) | ~np.isfinite(arr), 0.0, arr).astype(np.float32)
            else:
                arr = arr.astype(np.float32, copy=False)
                if key == "rgba" and arr.ndim == 3 and arr.shape[2] == 3:
                    arr = np.concatenate([arr, np.ones(arr.shape[:2] + (1,), np.float32)], axis=2)
            out[key] = arr
    if not out:
        raise UserError(f"no render passes found; expected channels like 'ViewLayer.Combined' "
                        f"(found {[n for p in parts for n in p.channels][:8]})", where=str(path))
    return out


def write_passes(path: str | Path, passes: dict[str, np.ndarray], window=None, *, frame_size=None,
                 compression: str = "zip") -> None:
    """Write full-frame {key: array} as one multilayer EXR (atomically) in Blender's naming.

    `window` (x0, y0, x1, y1), exclusive ends: store only that part (the EXR data window);
    `read_passes` restores the full frame. Rendering a border region leaves nothing outside
    it, so storing it would only cost compression time and disk.
    `frame_size` (W, H): the arrays hold only `window` (inside the frame, non-empty), not the
    full frame: the render stage never builds the empty rest.
    `compression`: a lossless OpenEXR codec, one of COMPRESSIONS. ZIP (default) is the
    smallest of the widely readable ones; "none" suits a file read back once and deleted
    (docs/render.md, cost section: time and size of each).
    """
    OpenEXR = _openexr()

    if compression not in COMPRESSIONS:
        raise ValueError(f"EXR compression {compression!r}: expected one of {sorted(COMPRESSIONS)}")
    if frame_size is not None:
        W, H = int(frame_size[0]), int(frame_size[1])
        x0, y0, x1, y1 = (int(v) for v in window)
        if not (0 <= x0 < x1 <= W and 0 <= y0 < y1 <= H):
            raise ValueError(f"window {window} must be a non-empty box inside the {W}x{H} frame")
        for key, arr in passes.items():
            if np.shape(arr)[:2] != (y1 - y0, x1 - x0):
                raise ValueError(f"pass {key!r}: {np.shape(arr)[:2]} is not the window's {(y1 - y0, x1 - x0)}")
        ox, oy = x0, y0  # array index = frame pixel - (ox, oy)
    else:
        H, W = next(iter(passes.values())).shape[:2]
        x0, y0, x1, y1 = window if window is not None else (0, 0, W, H)
        x0, y0, x1, y1 = max(0, int(x0)), max(0, int(y0)), min(W, int(x1)), min(H, int(y1))
        if x1 <= x0 or y1 <= y0:
            x0, y0, x1, y1 = 0, 0, 1, 1  # EXR needs a non-empty data window
        ox = oy = 0

    channels = {}
    for key, arr in passes.items():
        if key not in KEY_PASSES:
            raise ValueError(f"unknown pass key {key!r}; expected one of {sorted(KEY_PASSES)}")
        name = f"ViewLayer.{KEY_PASSES[key]}"
        a = np.ascontiguousarray(np.asarray(arr)[y0 - oy:y1 - oy, x0 - ox:x1 - ox], dtype=np.float32)
        if a.ndim == 2:
            name += ".X" if key == "index" else ".Z" if key == "depth" else ".V"
        channels[name] = a
    header = {"compression": getattr(OpenEXR, COMPRESSIONS[compression]), "type": OpenEXR.scanlineimage,
              "dataWindow": (np.array([x0, y0], np.int32), np.array([x1 - 1, y1 - 1], np.int32)),
              "displayWindow": (np.array([0, 0], np.int32), np.array([W - 1, H - 1], np.int32))}
    with atomic_path(path) as tmp:
        OpenEXR.File(header, channels).write(str(tmp))


def empty_passes(width: int, height: int, keys) -> dict[str, np.ndarray]:
    """What a frame with nothing to render looks like: transparent, id 0, no depth, no shadow."""
    out = {}
    for key in keys:
        if key == "rgba":
            out[key] = np.zeros((height, width, 4), np.float32)
        elif key in ("index", "depth"):
            out[key] = np.zeros((height, width), np.float32)
        elif key == "shadow_catcher":
            out[key] = np.ones((height, width, 3), np.float32)  # multiplicative: 1 = unshadowed
        else:
            out[key] = np.zeros((height, width, 3), np.float32)
    return out
