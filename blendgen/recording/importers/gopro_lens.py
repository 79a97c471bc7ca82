"""GoPro lenses from Gyroflow's lens-profile database (blendgen/recording/lenses/gopro.json,
CC0; `tools/make_gopro_lenses.py` builds it).

A GoPro file names its camera (moov/udta FIRM: "HD5.02..." is a HERO5 Black) but not, on the
models here, its lens mode (Wide, Linear, ...), which changes the field of view from about 85
to 120 degrees: the user says it (`blendgen import gopro --lens linear`). The profile's fisheye
intrinsics are scaled to the video's size (the same aspect: GoPro's low-resolution proxies and
transcodes keep the frame), and its readout time is written when the database lists one for
the video's own size and frame rate (not one as long as the frame: a placeholder).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from blendgen.errors import UserError
from blendgen.geometry import Camera

DATA = Path(__file__).resolve().parents[1] / "lenses" / "gopro.json"
# FIRM prefix -> camera model (the database's names)
FIRMWARE_MODELS = {"HD3.02": "HERO3 Silver", "HD5.02": "HERO5 Black", "HD5.03": "HERO5 Session",
                   "HD6.01": "HERO6 Black", "HD7.01": "HERO7 Black", "HD8.01": "HERO8 Black",
                   "HD9.01": "HERO9 Black", "H21.01": "HERO10 Black", "H22.01": "HERO11 Black"}
FPS_TOL = 0.05       # frame rates that are the same mode (29.97 vs 30.0 are not)
PLACEHOLDER_FRACTION = 0.98  # a readout this close to the frame period is not a measurement


@dataclass
class GoProLens:
    camera: Camera
    readout_s: float | None
    description: str
    notes: list[str] = field(default_factory=list)


@lru_cache(maxsize=1)
def profiles() -> tuple[dict, ...]:
    return tuple(json.loads(DATA.read_text())["profiles"])


def model_from_firmware(firmware: str) -> str | None:
    return FIRMWARE_MODELS.get(firmware[:6])


def _stabilised(p: dict) -> bool:
    return "EIS" in p["stabilisation"].upper() and "NO-EIS" not in p["stabilisation"].upper()


def _of(model: str) -> list[dict]:
    """`model`'s profiles (HyperSmooth Boost's extra crop is not offered)."""
    return [p for p in profiles() if p["camera"] == model and "BOOST" not in p["stabilisation"].upper()]


def modes(model: str) -> list[str]:
    """The lens modes the database has for `model` ("linear", "wide", "wide --eis", ...)."""
    return sorted({p["lens"].lower() + (" --eis" if _stabilised(p) else "") for p in _of(model)})


def find_lens(model: str, mode: str, eis: bool, width: int, height: int, fps: float) -> GoProLens:
    """The profile of `model` in lens `mode` (with or without electronic stabilisation) for a
    `width` x `height` video at `fps`. UserError naming what exists when nothing matches."""
    known = sorted({p["camera"] for p in profiles()})
    if model not in known:
        raise UserError(f"no lens profile for a GoPro {model}; the database has {', '.join(known)} "
                        "(or give the lens with --hfov)")
    cands = [p for p in _of(model) if p["lens"].lower() == mode.lower() and _stabilised(p) == eis]
    if not cands:
        raise UserError(f"--lens {mode}{' --eis' if eis else ''}: no {model} profile; it has: "
                        f"{'; '.join(modes(model))}")
    aspect = width / height
    same = [p for p in cands if abs(p["size"][0] / p["size"][1] - aspect) < 0.01 * aspect]
    if not same:
        sizes = sorted({f"{p['size'][0]}x{p['size'][1]}" for p in cands})
        raise UserError(f"--lens {mode}: the {model} profiles are for {', '.join(sizes)}, none with this "
                        f"video's aspect ({width}x{height})")
    listed = [p for p in same if any((r[0], r[1]) == (width, height) for r in p["readouts"])]
    best = min(listed or same, key=lambda p: p["rms_px"] if p["rms_px"] is not None else np.inf)
    W, H = best["size"]
    fx, fy, cx, cy = best["intrinsics"]
    cam = Camera(W, H, fx, fy, cx, cy, list(best["distortion"]), "equidistant")
    cam = cam.scaled(width, height) if (W, H) != (width, height) else cam
    why = cam.too_wide()
    if why:
        raise UserError(f"--lens {mode}: the {model}'s profile {why}")
    stab = f" {best['stabilisation']}" if best["stabilisation"] else ""
    rms = f", RMS {best['rms_px']:.2f} px" if best["rms_px"] is not None else ""
    desc = (f"GoPro lens profile: {model} {best['lens']}{stab} ({best['source']} in Gyroflow's lens_profiles, "
            f"CC0; calibrated at {W}x{H}{rms}), scaled to {width}x{height}")
    readout, notes = _readout(same, width, height, fps)
    return GoProLens(cam, readout, desc, notes)


def _readout(same: list, width: int, height: int, fps: float) -> tuple[float | None, list[str]]:
    """The database's readout for this size and frame rate, only for a size the camera records
    (a copy's recorded size is unknown, and the readout changes with it: HERO5 Black Wide at
    29.97 fps, 26.7 ms at 2.7K and 16.7 ms at 4K)."""
    listed = [r for p in same for r in p["readouts"] if abs(r[2] - fps) < FPS_TOL and r[3] is not None]
    if not listed:
        return None, [f"no readout is listed for {fps:.2f} fps: rolling shutter not corrected (calib.yaml "
                      "camera.rolling_shutter_s: the value, or auto to estimate it)"]
    exact = [r for r in listed if (r[0], r[1]) == (width, height)]
    # a readout as long as the frame leaves the sensor no blanking time: the database's
    # placeholder (HERO5 Black at 29.97 fps: 33.367 ms = 1 / 29.97 s), not a measurement. On the
    # Karma clip it turned VO's rotation 1.135x the gyro's instead of 1.025x, and `auto` finds 0
    rows = [r for r in listed if r[3] < PLACEHOLDER_FRACTION * 1e3 / r[2]]
    real = [r for r in exact if r in rows]
    if real:
        r = float(np.median([x[3] for x in real])) / 1e3
        return r, [f"rolling shutter readout {r * 1e3:.2f} ms from the profile ({width}x{height} at {fps:.2f} fps)"]
    if exact or not rows:
        why = f"only the frame period (a placeholder) is listed for {fps:.2f} fps"
    else:
        opts = ", ".join(sorted({f"{r[3]:.1f} ms at {r[0]}x{r[1]}" for r in rows}))
        why = f"{width}x{height} is a copy: the readout depends on the recorded size ({opts})"
    return None, [f"{why}: rolling shutter not corrected (calib.yaml camera.rolling_shutter_s: the value, or "
                  "auto to estimate it)"]
