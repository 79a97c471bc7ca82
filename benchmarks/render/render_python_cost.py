"""CPU and wall time per stage of RenderSession.render_frame on the bench_render frame.

Usage (from a checkout root; measures the blendgen that PYTHONPATH puts first):
  PYTHONPATH=$PWD nice -n 5 .venv/bin/python benchmarks/render/render_python_cost.py [--frames 7] [--samples 1]
      [--compression zip] [--k1 -0.2] [--save out.exr] [--json out.json]

Per frame: wall seconds from render_frame's own timings, CPU seconds (user + system, all
threads: resource.getrusage) of the write stage (paste, finish, EXR write), the amodal
rasteriser and the rest (scene sync, Cycles render, reading its EXRs). Medians over the
frames after one warm-up frame. Works on checkouts before issue 17's Python cuts too (it
times whichever write functions the checkout has).
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: its blendgen, benchmarks.common


def cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=7)
    ap.add_argument("--samples", type=int, default=1)
    ap.add_argument("--denoise", action="store_true")
    ap.add_argument("--compression", default=None, help="EXR codec (checkouts with the option only)")
    ap.add_argument("--k1", type=float, default=0.0, help="radial lens distortion (0: the benchmark's pinhole)")
    ap.add_argument("--save", type=Path, help="keep the first measured frame's EXR here")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()

    from benchmarks.render import bench_render as B
    import blendgen.render.session as S
    from blendgen.job.schema import Render

    acc = {"write": 0.0, "amodal": 0.0}

    def timed(key, fn):
        def wrapper(*a, **k):
            c = cpu()
            try:
                return fn(*a, **k)
            finally:
                acc[key] += cpu() - c
        return wrapper

    if hasattr(S, "passes_mod"):  # after: one function pastes, finishes and writes
        S.passes_mod.write_frame = timed("write", S.passes_mod.write_frame)
    else:  # before: three steps
        S.RenderSession._uncrop = timed("write", S.RenderSession._uncrop)
        S.RenderSession._finish_passes = timed("write", S.RenderSession._finish_passes)
        S.write_passes = timed("write", S.write_passes)
    S.RenderSession._amodal = timed("amodal", S.RenderSession._amodal)

    W, H, _ref, cam, build, build_name, plan, tmp = B._setup(argparse.Namespace(quick=False, ref_samples=None))
    if args.k1:
        from blendgen.geometry import Camera

        cam = Camera(cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy, [args.k1, 0.0, 0.0, 0.0, 0.0])
    sess = S.RenderSession(None, None, Render(), cam, object_builder=build)
    sess.render = Render(samples=args.samples, denoise=args.denoise)
    kw = {"compression": args.compression} if args.compression else {}
    sess.render_frame(plan, tmp / "warm.exr", B.OUTPUTS, **kw)
    rows = []
    for i in range(args.frames):
        acc.update(write=0.0, amodal=0.0)
        out = tmp / f"f{i}.exr"
        c0 = cpu()
        info = sess.render_frame(plan, out, B.OUTPUTS, **kw)
        total = cpu() - c0
        t = info["timings"]
        rows.append({"wall_render": t["render"], "wall_write": t["write"], "wall_amodal": t["amodal"],
                     "wall_total": t["total"], "cpu_write": acc["write"], "cpu_amodal": acc["amodal"],
                     "cpu_rest": total - acc["write"] - acc["amodal"], "cpu_total": total,
                     "exr_mb": out.stat().st_size / 1e6})
        if i == 0 and args.save:
            args.save.write_bytes(out.read_bytes())
            if args.json:
                args.json.with_suffix(".info.json").write_text(json.dumps(info, indent=1, default=str))
    med = {k: statistics.median(r[k] for r in rows) for k in rows[0]}
    print(f"{W}x{H}, k1 {args.k1}, {build_name}, {args.samples} spp, denoise {args.denoise}, {args.frames} frames, "
          f"regions {info.get('regions')}")
    for k, v in med.items():
        print(f"  {k:12s} {v:7.3f}")
    if args.json:
        args.json.write_text(json.dumps({"median": med, "rows": rows}, indent=1))
    sess.close()


if __name__ == "__main__":
    main()
