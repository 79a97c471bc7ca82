"""Build blendgen/recording/lenses/gopro.json from a checkout of Gyroflow's lens-profile
database (https://github.com/gyroflow/lens_profiles, CC0-1.0):

    git clone https://github.com/gyroflow/lens_profiles /tmp/lens_profiles
    python tools/make_gopro_lenses.py /tmp/lens_profiles

Kept: GoPro HERO profiles marked official, in OpenCV's fisheye model, without a digital lens
(SuperView and similar are a warp on top of the fisheye) and without add-on lenses
(anamorphic adapters, ND filters). Per profile: the calibrated size, the fisheye intrinsics,
and the frame readout times Gyroflow lists for the resolutions and frame rates that share
the lens (`compatible_settings`). Run at build time only; blendgen never downloads it.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ADD_ONS = ("anamorph", "kase", "neewer", "neweer", "nd16", "nd ")
OUT = Path(__file__).resolve().parents[1] / "blendgen" / "recording" / "lenses" / "gopro.json"


def keep(d: dict, name: str) -> bool:
    text = " ".join(str(d.get(k) or "") for k in ("name", "lens_model", "note", "camera_setting")).lower() + name.lower()
    return (d.get("official") is True and d.get("camera_brand") == "GoPro"
            and str(d.get("camera_model", "")).startswith("HERO") and d.get("use_opencv_fisheye", True)
            and d.get("lens_model") and not d.get("digital_lens") and not any(a in text for a in ADD_ONS)
            and len((d.get("fisheye_params") or {}).get("distortion_coeffs") or []) == 4)


def main(repo: str) -> None:
    root = Path(repo)
    commit = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True,
                            text=True).stdout.strip() or "unknown"
    profiles = []
    for path in sorted((root / "GoPro").glob("*.json")):
        d = json.loads(path.read_text())
        if not keep(d, path.name):
            continue
        fp = d["fisheye_params"]
        K = fp["camera_matrix"]
        size = [int(d["calib_dimension"]["w"]), int(d["calib_dimension"]["h"])]
        readouts = [[*size, float(d["fps"]), d.get("frame_readout_time")]] if d.get("fps") else []
        readouts += [[int(c["width"]), int(c["height"]), float(c["fps"]), c.get("frame_readout_time")]
                     for c in d.get("compatible_settings") or []]
        profiles.append({
            "camera": d["camera_model"], "lens": d.get("lens_model") or "", "stabilisation": d.get("note") or "",
            "size": size, "intrinsics": [K[0][0], K[1][1], K[0][2], K[1][2]],
            "distortion": [float(v) for v in fp["distortion_coeffs"]], "rms_px": fp.get("RMS_error"),
            "source": path.relative_to(root).as_posix(),
            # [width, height, fps, frame readout (ms) or null]
            "readouts": [[w, h, round(f, 3), None if r is None else round(float(r), 5)] for w, h, f, r in readouts]})
    doc = {"source": "https://github.com/gyroflow/lens_profiles", "commit": commit, "licence": "CC0-1.0",
           "model": "OpenCV fisheye (Kannala-Brandt k1..k4), pixels of the calibrated size",
           "profiles": profiles}
    # one profile per line: small, and a database update diffs profile by profile
    head = json.dumps({k: v for k, v in doc.items() if k != "profiles"})[:-1]
    OUT.write_text(head + ', "profiles": [\n' + ",\n".join(json.dumps(p) for p in profiles) + "\n]}\n")
    print(f"{len(profiles)} profiles -> {OUT}")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    main(sys.argv[1])
