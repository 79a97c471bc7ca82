"""GPU render cost (issue 17): blendgen's defaults against the fair naive baseline, on a GPU.

The frame, the reference, the PSNR and the naive baseline are bench_render.py's (1280x720,
five objects with sun shadows; naive = full frame, the whole road as shadow catcher,
Cycles' defaults read from Blender's RNA, OIDN on, its sample count searched for blendgen's
PSNR); every session here is opened with `render.device: GPU`. On a GPU the cost is wall
seconds per frame (the GPU is the resource a farm pays for; the host's CPU seconds are
reported beside them). With --cpu the same frame is also rendered on this machine's CPU
cores (blendgen's defaults and the naive render at the count found on the GPU), so that the
two devices compare on one machine.

    python benchmarks/render/bench_render_gpu.py [--repeats 5] [--pairs 5] [--cpu] [--quick] [--device CPU]

Exits with a message, writing nothing, when Cycles finds no GPU.
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: its blendgen, benchmarks.common

from benchmarks.render import bench_render as br  # noqa: E402

from blendgen.atomic import write_text  # noqa: E402
from blendgen.job.schema import Render  # noqa: E402


def gpu_name() -> str:
    try:
        out = subprocess.run(["nvidia-smi", "--query-gpu=name,driver_version", "--format=csv,noheader"],
                             capture_output=True, text=True, timeout=20).stdout.strip()
        return out or "unknown GPU"
    except (OSError, subprocess.SubprocessError):
        return "unknown GPU"


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=5, help="runs per measured configuration (median)")
    ap.add_argument("--pairs", type=int, default=5, help="interleaved blendgen / naive pairs in fresh sessions")
    ap.add_argument("--ref-samples", type=int, default=256)
    ap.add_argument("--max-samples", type=int, default=256)
    ap.add_argument("--cpu", action="store_true", help="also render blendgen and the naive baseline on the CPU")
    ap.add_argument("--device", choices=("GPU", "CPU"), default="GPU",
                    help="CPU: the same measurements on the CPU (a check of this script where no GPU is)")
    ap.add_argument("--quick", action="store_true", help="640x360")
    args = ap.parse_args()

    from blendgen.render import effects as fx
    from blendgen.render.session import RenderSession

    W, H, _, cam, build, build_name, plan, tmp = br._setup(args)
    reps, t_start = args.repeats, time.perf_counter()

    def session(device=args.device, naive=False):
        return br.warm_session(cam, build, plan, tmp, catch="ground" if naive else "patches",
                               blender_defaults=naive, device=device)

    # ---- the reference, on the GPU
    ref_sess = RenderSession(None, None, Render(device=args.device), cam, object_builder=build,
                             catch_shadows_on="ground")
    if args.device == "GPU" and not ref_sess.device.startswith("GPU"):
        shutil.rmtree(tmp, ignore_errors=True)
        sys.exit(f"bench_render_gpu: Cycles found no GPU here ({ref_sess.device}); nothing written")
    device = gpu_name() if args.device == "GPU" else "this machine's CPU"
    ref_sess.scene.cycles.seed = 7919
    t_ref, info_ref, ref = br.run_config(ref_sess, plan, Render(samples=args.ref_samples, denoise=False,
                                                                adaptive_threshold=0), tmp / "ref.exr")
    backend = ref_sess.device
    ref_sess.close()
    ref_img, mask = br.display(ref), br._object_mask(ref, info_ref)
    print(f"{device}, Cycles {backend}; reference {args.ref_samples} spp: {t_ref:.1f} s", flush=True)

    def row(name, r, t, info, p):
        q = br.psnr(br.display(p), ref_img, mask)
        print(f"{name:34s} spp {r.samples:4d}  wall {t:6.3f} s  host cpu {info['cpu_s']:6.2f} s  {q:6.2f} dB",
              flush=True)
        return {"config": name, "samples": r.samples, "wall_s": t, "cpu_s": info["cpu_s"], "psnr_db": q,
                "regions": info.get("regions") or "full", "timings": info.get("timings")}

    # ---- blendgen at its defaults, and with one region around all objects
    sess = session()
    warm_blend = sess.warm_s
    blend = row("blendgen defaults", Render(), *br.run_config(sess, plan, Render(), tmp / "b.exr", reps))
    over_name = "REGION_OVERHEAD_FRACTION_GPU" if args.device == "GPU" else "REGION_OVERHEAD_FRACTION"
    over0 = getattr(fx, over_name)
    variants = []  # on a GPU: what denoising there and the GPU's region clustering save
    if args.device == "GPU":
        sess.scene.cycles.denoising_use_gpu = False
        variants.append(row("blendgen, OIDN on the CPU", Render(), *br.run_config(sess, plan, Render(), tmp / "b.exr", reps)))
        sess.scene.cycles.denoising_use_gpu = True
        setattr(fx, over_name, fx.REGION_OVERHEAD_FRACTION)
        variants.append(row("blendgen, the CPU's region clustering", Render(),
                            *br.run_config(sess, plan, Render(), tmp / "b.exr", reps)))
    setattr(fx, over_name, 1e12)
    blend_one = row("blendgen, one region", Render(), *br.run_config(sess, plan, Render(), tmp / "b1.exr", reps))
    # the clusters: two cars side by side (one region) and at opposite edges (two regions / one)
    cl = {}
    for name, pp in br.pair_plans().items():
        sess.render = Render(samples=1, denoise=False)
        sess.render_frame(pp, tmp / "warm.exr", br.OUTPUTS)
        for mode, over in (("clustered", over0), ("one region", 1e12)):
            if name == "side by side" and mode == "one region":
                continue
            setattr(fx, over_name, over)
            t, info, _ = br.run_config(sess, pp, Render(), tmp / "pair.exr", max(reps, 5))
            cl[f"{name}, {mode}"] = {"wall_s": t, "cpu_s": info["cpu_s"], "regions": info["regions"]}
            print(f"{name:15s} {mode:10s} regions {info['regions']}  wall {t:.3f} s", flush=True)
    setattr(fx, over_name, over0)
    sess.close()

    # ---- the fair baseline: the lowest naive sample count reaching blendgen's PSNR
    sess = session(naive=True)
    defaults = sess.defaults

    def naive_at(n):
        r = Render(samples=n, denoise=True, region=False)
        return row("naive, Blender defaults", r, *br.run_config(sess, plan, r, tmp / "n.exr"))

    found, tried = br.search_samples(naive_at, blend["psnr_db"], 1, args.max_samples)
    final = None
    if found is not None:
        r = Render(samples=found["samples"], denoise=True, region=False)
        final = row("naive at the found count", r, *br.run_config(sess, plan, r, tmp / "n.exr", reps))
    sess.close()

    # ---- interleaved pairs, each half in a fresh session
    pair_ratios = []
    for _ in range(args.pairs if final else 0):
        wall = {}
        for naive in (False, True):
            s = session(naive=naive)
            r = Render(samples=final["samples"], denoise=True, region=False) if naive else Render()
            wall[naive] = br.run_config(s, plan, r, tmp / "pair.exr")[0]
            s.close()
        pair_ratios.append(wall[True] / wall[False])
        print(f"pair: blendgen {wall[False]:.3f} s, naive {wall[True]:.3f} s -> {pair_ratios[-1]:.2f}x", flush=True)

    # ---- the same frame on this machine's CPU
    cpu_rows = []
    if args.cpu and final:
        for naive in (False, True):
            s = session("CPU", naive)
            r = Render(samples=final["samples"], denoise=True, region=False) if naive else Render()
            cpu_rows.append(row(("naive" if naive else "blendgen") + " on the CPU", r,
                                *br.run_config(s, plan, r, tmp / "c.exr", reps)))
            s.close()
    total = time.perf_counter() - t_start

    # ---- report
    ratio = final["wall_s"] / blend["wall_s"] if final else None
    side = cl["side by side, clustered"]["wall_s"]
    cmd = "python benchmarks/render/bench_render_gpu.py" + (f" --repeats {reps}" if reps != 5 else "") + \
        (f" --pairs {args.pairs}" if args.pairs != 5 else "") + (" --cpu" if args.cpu else "") + \
        (" --quick" if args.quick else "") + (" --device CPU" if args.device == "CPU" else "")
    lines = [f"# Render cost on the {args.device}: the fair baseline", "",
             f"Command: `{cmd}` on {device}, Cycles {backend} ({total / 60:.1f} min; "
             f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}). Frame {W}x{H}, 5 objects ({build_name}) "
             f"with sun shadows, PSNR over the {int(mask.sum())} object and shadow pixels against a "
             f"{args.ref_samples}-sample naive reference rendered on the same device ({t_ref:.1f} s). Wall seconds "
             "around `render_frame` (render, denoise, EXR written), medians; the host's CPU seconds beside them. "
             f"First frame of a session (kernels, BVH, objects): {warm_blend:.1f} s.", "",
             "Naive = full frame, the whole road as shadow catcher, Cycles' defaults (" +
             ", ".join(f"{k} {v}" for k, v in defaults.items()) + "), OIDN on" +
             (", denoising on the GPU (Blender's default is the CPU)" if args.device == "GPU" else "") +
             "; samples searched for blendgen's PSNR.", "",
             f"| configuration | samples | {args.device} wall (s) | host CPU (s) | PSNR (dB) |", "|---|---|---|---|---|"]
    for r in [blend] + variants + [blend_one] + tried + ([final] if final else []) + cpu_rows:
        lines.append(f"| {r['config']} | {r['samples']} | {r['wall_s']:.3f} | {r['cpu_s']:.2f} | {r['psnr_db']:.2f} |")
    lines.append("")
    if final:
        lines.append(f"- Lowest naive count reaching {blend['psnr_db']:.2f} dB: **{final['samples']}**; blendgen "
                     f"is **{ratio:.1f}x cheaper in {args.device} wall seconds** ({final['wall_s']:.3f} -> "
                     f"{blend['wall_s']:.3f} s).")
    else:
        lines.append(f"- No naive count up to {args.max_samples} reached {blend['psnr_db']:.2f} dB.")
    if pair_ratios:
        lines.append(f"- Interleaved pairs (fresh sessions): {' / '.join(f'{x:.2f}x' for x in pair_ratios)}, "
                     f"median **{statistics.median(pair_ratios):.2f}x**.")
    for r in [blend] + ([final] if final else []):
        if r.get("timings"):
            lines.append(f"- {r['config']}, one frame by phase (s): " +
                         ", ".join(f"{k} {v:.3f}" for k, v in r["timings"].items()) + f"; regions {r['regions']}.")
    lines += ["", f"| layout | regions | {args.device} wall (s) | vs side by side |", "|---|---|---|---|"]
    for k, c in cl.items():
        lines.append(f"| {k} | {len(c['regions'])} | {c['wall_s']:.3f} | {c['wall_s'] / side - 1:+.0%} |")
    md = "\n".join(lines)
    br.RESULTS.mkdir(parents=True, exist_ok=True)
    stem = "render_gpu" + ("" if args.device == "GPU" else "_cpu") + ("_quick" if args.quick else "")
    write_text(br.RESULTS / f"{stem}.json", json.dumps({
        "device": device, "backend": backend, "blendgen": blend,
        "blendgen_variants": variants, "blendgen_one_region": blend_one,
        "naive_tried": tried, "naive_final": final, "ratio_wall": ratio, "pair_ratios": pair_ratios,
        "clusters": cl, "cpu": cpu_rows, "defaults": defaults, "first_frame_s": warm_blend}, indent=1, default=str))
    write_text(br.DOC.with_name(f"{stem}.md"), md + "\n")
    shutil.rmtree(tmp, ignore_errors=True)
    print("\n" + md)


if __name__ == "__main__":
    main()
