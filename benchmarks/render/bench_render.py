"""Render benchmark: what accuracy costs in time, and whether memory stays flat.

Scene: a 1280x720 frame (640x360 with --quick) of a ground-plane road with 5 objects
(2 cars, a truck, a person, a bicycle: assets_procedural's builders when available, else
plain boxes) under a visible sun, so every object casts a shadow on the road.

Quality: PSNR over the object and shadow pixels of the frame as the post stage uses it
(premultiplied RGBA over a grey background darkened by the shadow-catcher pass, clipped,
gamma 2.2) against a high-sample render of the naive scene (the whole road as shadow
catcher, no denoising, no adaptive sampling), so any bias of the driver's shortcuts counts
against them. The reference is rendered region-limited: the region contains every object
and shadow pixel by construction (checked below), so over the measured pixels it is the
full-frame reference.
A noisy reference makes the measured PSNR a lower bound (its own noise adds to the error).

The fair baseline (issue 17): a naive full-frame render with Blender's defaults (the whole
road as shadow catcher, no border region, Cycles' default light paths, adaptive sampling and
OIDN denoising as a new Blender 5.0 scene has them), at the lowest sample count that reaches
blendgen's own PSNR at its default settings: the samples are searched (doubling, then
bisection), not picked; CPU seconds of both from the same run.

Clusters (issue 17): two cars side by side (one border region) and the same two cars at
opposite edges of the frame (two regions, one per cluster, pasted), CPU seconds, and the
PSNR of the pasted passes against one region around both.

Sweep (--sweep): samples 4..128, denoise on/off, bounces, for
- "effects": this driver's decisions (border region, shadow catcher only on patches where
  shadows can fall, adaptive sampling),
- "full frame": the same without the border region,
- "naive": full frame, the whole road as shadow catcher, no adaptive sampling.
Speedup at equal quality: the fastest naive configuration reaching the target PSNR against
the fastest "effects" configuration reaching it.

Memory: RSS over 300 frames in one session (objects moving, one replaced every 10 frames).

    .venv/bin/python benchmarks/render/bench_render.py [--quick] [--ref-samples N] [--sweep] [--memory-frames N]
"""

from __future__ import annotations

import argparse
import json
import resource
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: its blendgen, benchmarks.common
from benchmarks.common import DOCS, RESULTS  # noqa: E402

from blendgen.atomic import write_text  # noqa: E402
from blendgen.geometry import Camera, R_world_cam_from_ypr, make_pose  # noqa: E402
from blendgen.job.schema import Render  # noqa: E402
from blendgen.plan import FramePlan, PlacedObject  # noqa: E402
from blendgen.render.exr import read_passes  # noqa: E402

DOC = DOCS / "render_fair.md"
TARGET_DB = 35.0
SUN = {"sun_direction": [0.45, -0.35, 0.82], "sun_strength": 3.0, "sun_color": [1.0, 0.97, 0.92],
       "sun_angle_deg": 0.53, "sky_color": [0.5, 0.6, 0.8], "sky_strength": 1.0, "sun_visible": True}
OUTPUTS = {"rgba", "index", "shadow_catcher", "lighting"}  # what the pipeline asks for by default
T = make_pose(R_world_cam_from_ypr(0.0, -0.03), [0.0, 0.0, 1.5])


def scene_objects() -> list[PlacedObject]:
    return [PlacedObject(1, "car", (14.0, 2.0, 0.0), 0.2, (4.5, 1.8, 1.5), variant={"seed": 1}),
            PlacedObject(2, "person", (9.0, -2.5, 0.0), 0.0, (0.5, 0.6, 1.8), variant={"seed": 2}),
            PlacedObject(3, "truck", (28.0, -3.5, 0.0), 0.0, (9.0, 2.5, 3.5), variant={"seed": 3}),
            PlacedObject(4, "bicycle", (11.0, -4.5, 0.0), 1.3, (1.8, 0.6, 1.1), variant={"seed": 4}),
            PlacedObject(5, "car", (20.0, 5.5, 0.0), 3.1, (4.5, 1.8, 1.5), variant={"seed": 5})]


def builder():
    try:
        from assets_procedural.objects import build_object
        return build_object, "assets_procedural.objects.build_object"
    except ImportError:
        from blendgen.render.primitives import box_object
        return box_object, "blendgen.render.primitives.box_object (assets_procedural.objects not available)"


def display(p: dict) -> np.ndarray:
    """What a viewer sees after compositing over a grey road: [0,1] gamma-2.2 RGB."""
    rgba, sc = p["rgba"], p.get("shadow_catcher", np.ones(p["rgba"].shape[:2] + (3,), np.float32))
    comp = rgba[..., :3] + (1.0 - rgba[..., 3:4]) * 0.5 * sc
    return np.clip(comp, 0, 1) ** (1 / 2.2)


def psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
    mse = float(np.mean((a[mask] - b[mask]) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(1.0 / mse)


def pareto(points):
    """Indices of (time, psnr) points not dominated by a faster-and-better one."""
    order = sorted(range(len(points)), key=lambda i: (points[i][0], -points[i][1]))
    front, best = [], -np.inf
    for i in order:
        if points[i][1] > best:
            front.append(i)
            best = points[i][1]
    return front


def cpu_s() -> float:
    """CPU seconds of this process, all threads: less sensitive than wall time to the other
    jobs sharing the two cores."""
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def use_blender_defaults(sess) -> dict:
    """Make a session sample like a new Blender scene: Cycles' own defaults for light paths,
    adaptive sampling, light tree and denoiser quality, read from Blender's RNA (not typed in
    here); only the sample count and denoise on/off come from the Render settings."""
    import bpy

    rna = type(sess.scene.cycles).bl_rna.properties  # the Cycles add-on registers this type
    names = ("use_adaptive_sampling", "adaptive_threshold", "adaptive_min_samples", "max_bounces",
             "diffuse_bounces", "glossy_bounces", "transmission_bounces", "transparent_max_bounces",
             "volume_bounces", "caustics_reflective", "caustics_refractive", "sample_clamp_direct",
             "sample_clamp_indirect", "use_light_tree", "denoising_prefilter", "denoising_quality",
             "denoising_input_passes", "denoiser")
    # (an enum whose default depends on the build, e.g. the denoiser, reads "": the session's
    # OpenImageDenoise stays)
    defaults = {n: rna[n].default for n in names if rna[n].default != ""}

    def set_sampling(s: dict):
        cy = sess.scene.cycles
        cy.samples = s["samples"]
        cy.use_denoising = s["denoise"]
        for n, v in defaults.items():
            setattr(cy, n, v)

    sess._set_sampling = set_sampling
    return {k: (v if isinstance(v, (int, float, bool, str)) else str(v)) for k, v in defaults.items()}


def warm_session(cam, build, plan, tmp: Path, *, catch: str = "patches", blender_defaults: bool = False,
                 device: str = "CPU"):
    """A render session as a worker holds it: its first frame (kernels, BVH, objects) rendered
    at 1 sample, so that what is timed afterwards is per frame (`warm_s`: that first frame).
    `catch`: "patches" (blendgen) or "ground" (the whole road, as the naive render);
    `blender_defaults`: sample like a new Blender scene (`defaults`: what was read)."""
    from blendgen.render.session import RenderSession

    sess = RenderSession(None, None, Render(device=device), cam, object_builder=build, catch_shadows_on=catch)
    if blender_defaults:
        sess.defaults = use_blender_defaults(sess)
        # Blender's RNA says denoise on the CPU; a user rendering on a GPU ticks "Denoise on GPU"
        sess.scene.cycles.denoising_use_gpu = device == "GPU"
    sess.render = Render(samples=1, denoise=False)
    t0 = time.perf_counter()
    sess.render_frame(plan, tmp / "warm.exr", OUTPUTS)
    sess.warm_s = time.perf_counter() - t0
    return sess


def search_samples(measure, target_db: float, lo: int = 1, hi: int = 256, tried: dict | None = None):
    """Lowest sample count whose PSNR reaches ``target_db``: doubling from ``lo`` until one
    does, then bisection between the last miss and the first hit. ``measure(samples)`` renders
    and returns a row with ``psnr_db``. Returns (row of the lowest hit or None, all rows). With
    PSNR noisy in the samples the hit found has a miss one sample below it, which is not
    always the lowest count that would ever reach the target (the tried rows are reported).
    ``tried`` (sample count -> row) is shared between searches for several targets."""
    tried = {} if tried is None else tried

    def at(n):
        if n not in tried:
            tried[n] = measure(n)
        return tried[n]

    miss, hit = 0, lo
    while at(hit)["psnr_db"] < target_db:
        miss, hit = hit, hit * 2
        if hit > hi:
            return None, [tried[k] for k in sorted(tried)]
    while hit - miss > 1:
        mid = (miss + hit) // 2
        if at(mid)["psnr_db"] >= target_db:
            hit = mid
        else:
            miss = mid
    return tried[hit], [tried[k] for k in sorted(tried)]


def fitted_naive_cpu(tried: list, target_db: float):
    """The naive side's CPU seconds at exactly ``target_db``, less exposed to one noisy render:
    CPU s fitted as a + b * samples over all search renders (least squares), samples
    interpolated linearly in PSNR between the two counts around the target.
    Returns (samples, cpu_s, a, b) or None when the target is not bracketed."""
    rows = sorted(tried, key=lambda r: r["samples"])
    for lo, hi in zip(rows, rows[1:]):
        if lo["psnr_db"] < target_db <= hi["psnr_db"]:
            n = lo["samples"] + (hi["samples"] - lo["samples"]) * (target_db - lo["psnr_db"]) / (
                hi["psnr_db"] - lo["psnr_db"])
            b, a = np.polyfit([r["samples"] for r in rows], [r["cpu_s"] for r in rows], 1)
            return n, a + b * n, a, b
    return None


def run_config(sess, plan, render: Render, out: Path, repeats: int = 1):
    sess.render = render
    times, cpus = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), cpu_s()
        info = sess.render_frame(plan, out, OUTPUTS)
        times.append(time.perf_counter() - t0)
        cpus.append(cpu_s() - c0)
    info["cpu_s"] = statistics.median(cpus)
    return statistics.median(times), info, read_passes(out)


def memory_run(cam: Camera, frames: int, build) -> list[float]:
    from blendgen.render.session import RenderSession

    sess = RenderSession(None, None, Render(samples=1, denoise=False), cam, object_builder=build)
    rss = []
    with tempfile.TemporaryDirectory() as d:
        for f in range(frames):
            objs = []
            for o in scene_objects():
                oid = o.id + 100 * (f // 10) if o.id == 2 else o.id   # object 2 replaced every 10 frames
                objs.append(PlacedObject(oid, o.cls, (o.position[0] + 0.05 * (f % 40), o.position[1], 0.0),
                                         o.yaw + 0.01 * f, o.dims, variant=o.variant))
            info = sess.render_frame(FramePlan(f"f{f:06d}", f / 10, T.tolist(), objs, SUN),
                                     Path(d) / "m.exr", OUTPUTS)
            rss.append(info["rss_mb"])
    sess.close()
    return rss


def plot_results(rows, rss, W, H, ref_samples, png: Path) -> None:
    """PSNR against CPU time per frame (the steadier cost on shared cores), Pareto front;
    RSS per frame."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter, NullFormatter

    fig, ax = plt.subplots(1, 2, figsize=(12, 4.5))
    styles = {("effects", False): ("o", "tab:blue", "effects, no denoise"),
              ("effects", True): ("s", "tab:green", "effects + denoise"),
              ("full frame", True): ("^", "tab:orange", "full frame + denoise"),
              ("naive", False): ("x", "tab:red", "naive full frame"),
              ("default", True): ("*", "black", f"job default ({Render().samples} spp, denoise)")}
    for (fam, dn), (m, c, lab) in styles.items():
        pts = [r for r in rows if r["family"] == fam and r["denoise"] == dn and r["bounces"] == 4]
        if pts:
            ax[0].scatter([r["cpu_s"] for r in pts], [r["psnr_db"] for r in pts], marker=m, c=c, label=lab, s=50)
            for r in pts:
                ax[0].annotate(str(r["samples"]), (r["cpu_s"], r["psnr_db"]), fontsize=7,
                               xytext=(3, 3), textcoords="offset points")
    bn = [r for r in rows if r["bounces"] != 4]
    if bn:
        ax[0].scatter([r["cpu_s"] for r in bn], [r["psnr_db"] for r in bn], marker="D", c="tab:purple",
                      label="16 spp + denoise, bounces " + "/".join(str(r["bounces"]) for r in bn), s=30)
    pts = [(r["cpu_s"], r["psnr_db"]) for r in rows]
    front = pareto(pts)
    ax[0].plot([pts[i][0] for i in front], [pts[i][1] for i in front], "k--", lw=1, label="Pareto front")
    ax[0].axhline(TARGET_DB, color="grey", lw=0.8, ls=":")
    ax[0].set_xscale("log")
    ax[0].xaxis.set_minor_formatter(NullFormatter())
    ax[0].xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    ax[0].set_xlabel("CPU time per frame (s, both threads; wall on 2 free cores is about half)")
    ax[0].set_ylabel(f"PSNR over object+shadow pixels (dB) vs {ref_samples} spp")
    ax[0].set_title(f"{W}x{H}, 5 objects with shadows")
    ax[0].legend(fontsize=7)
    ax[1].plot(np.arange(len(rss)), rss)
    ax[1].set_xlabel("frame")
    ax[1].set_ylabel("RSS (MB)")
    ax[1].set_title(f"one session, {len(rss)} frames at 320x180")
    ax[1].set_ylim(0, max(rss) * 1.2)
    fig.tight_layout()
    fig.savefig(png, dpi=110)
    plt.close(fig)


def _object_mask(ref, info_ref) -> np.ndarray:
    """The reference's object and shadow pixels (what PSNR is measured on); all inside its region."""
    mask = (ref["rgba"][..., 3] > 0.02) | (ref["shadow_catcher"].min(axis=2) < 0.98)
    x0, y0, x1, y1 = info_ref["region"]
    inside = np.zeros_like(mask)
    inside[y0:y1, x0:x1] = True
    assert not np.any(mask & ~inside), "object/shadow pixels outside the region"
    return mask


def _setup(args):
    """Frame size, reference samples, camera, object builder, the benchmark frame and a temp dir."""
    W, H = (640, 360) if args.quick else (1280, 720)
    ref_samples = args.ref_samples or (128 if args.quick else 256)
    build, build_name = builder()
    plan = FramePlan("bench", 0.0, T.tolist(), scene_objects(), SUN)
    return (W, H, ref_samples, Camera.from_hfov(W, H, 70), build, build_name, plan,
            Path(tempfile.mkdtemp(prefix="bench_render_")))


def sweep(args):
    """The samples/denoise/bounces sweep against the no-denoise naive render, and memory."""
    W, H, ref_samples, cam, build, build_name, plan, tmp = _setup(args)
    rows = []
    t_start = time.perf_counter()

    # The naive render: full frame, the whole road catches shadows, no adaptive sampling. Its
    # high-sample version is the reference; the border region does not change the pixels it
    # measures (checked below), so the reference is rendered with it to save time.
    naive = warm_session(cam, build, plan, tmp, catch="ground")
    print(f"{W}x{H}, objects: {build_name}; reference {ref_samples} samples ...", flush=True)
    # Its own random sequence: with the same seed, an N-sample render would share its first
    # N samples with the reference and look better than it is.
    naive.scene.cycles.seed = 7919
    t_ref, info_ref, ref = run_config(naive, plan, Render(samples=ref_samples, denoise=False, adaptive_threshold=0),
                                      tmp / "ref.exr")
    naive.scene.cycles.seed = 0
    ref_img = display(ref)
    mask = _object_mask(ref, info_ref)
    print(f"reference: {t_ref:.1f} s, {int(mask.sum())} object+shadow pixels "
          f"({mask.mean():.1%} of the frame)", flush=True)

    samples = [4, 8, 16, 32, 64] if args.quick else [4, 8, 16, 32, 64, 128]
    configs = []
    for s in samples:
        for dn in (False, True):
            configs.append(("effects", dict(samples=s, denoise=dn)))
    for s in ([16, 64] if args.quick else [16, 64]):
        configs.append(("full frame", dict(samples=s, denoise=True, region=False)))
    for mb in ([1, 8] if args.quick else [1, 2, 8]):
        configs.append(("effects", dict(samples=16, denoise=True, max_bounces=mb)))

    def record(family, kw, sess, repeats=1):
        r = Render(**kw)
        t, info, p = run_config(sess, plan, r, tmp / "c.exr", repeats)
        q = psnr(display(p), ref_img, mask)
        row = {"family": family, "samples": r.samples, "denoise": r.denoise, "region": r.region,
               "bounces": r.max_bounces, "adaptive": r.adaptive_threshold > 0, "time_s": t, "cpu_s": info["cpu_s"],
               "psnr_db": q,
               "render_s": info["timings"]["render"], "repeats": repeats}
        rows.append(row)
        print(f"{family:10s} spp {r.samples:4d} denoise {str(r.denoise):5s} region {str(r.region):5s} "
              f"bounces {r.max_bounces}  {t:7.2f} s  (cpu {info['cpu_s']:7.2f} s)  {q:6.2f} dB", flush=True)
        return row

    for sp in ([8, 32] if args.quick else [16, 64]):
        record("naive", dict(samples=sp, denoise=False, region=False, adaptive_threshold=0), naive)
    naive.close()

    eff = warm_session(cam, build, plan, tmp)
    for family, kw in configs:
        record(family, kw, eff)
    default = record("default", {}, eff, repeats=3)  # job defaults (Render()), median of 3
    eff.close()

    frames = 60 if args.quick else 300
    mem_cam = Camera.from_hfov(320, 180, 70)
    rss = memory_run(mem_cam, frames, build)
    base = rss[min(10, len(rss) - 1)]
    growth = (max(rss[10:]) - base) / base if len(rss) > 10 else 0.0
    print(f"RSS over {frames} frames: {rss[0]:.0f} -> {rss[-1]:.0f} MB (max growth after frame 10: "
          f"{growth:+.1%})", flush=True)

    # ---- summary
    def fastest(fam, cond):
        # By CPU time: wall time on two shared cores swings with the other jobs.
        c = [r for r in rows if r["family"] in fam and cond(r)]
        return min(c, key=lambda r: r["cpu_s"]) if c else None

    ok = lambda r: r["psnr_db"] >= TARGET_DB  # noqa: E731
    best = fastest(("effects", "default"), ok)
    nv = fastest(("naive",), ok)
    naive_rows = [r for r in rows if r["family"] == "naive"]
    if best and nv:
        speed = (f"{nv['time_s'] / best['time_s']:.1f}x wall ({nv['time_s']:.1f} s -> {best['time_s']:.1f} s), "
                 f"{nv['cpu_s'] / best['cpu_s']:.1f}x CPU time ({nv['cpu_s']:.1f} -> {best['cpu_s']:.1f} CPU s)")
    elif best:
        slow = max(naive_rows, key=lambda r: r["psnr_db"])
        speed = (f"> {slow['cpu_s'] / best['cpu_s']:.1f}x CPU time: no naive configuration reached {TARGET_DB} dB "
                 f"(best {slow['psnr_db']:.1f} dB at {slow['cpu_s']:.1f} CPU s)")
    else:
        speed = f"no configuration reached {TARGET_DB} dB"
    total = time.perf_counter() - t_start

    RESULTS.mkdir(parents=True, exist_ok=True)
    png = RESULTS / ("render_sweep_quick.png" if args.quick else "render_sweep.png")
    plot_results(rows, rss, W, H, ref_samples, png)

    # ---- table
    cmd = ".venv/bin/python benchmarks/render/bench_render.py" + (" --quick" if args.quick else "")
    lines = [f"# Render benchmark{' (quick)' if args.quick else ''}", "",
             f"Command: `{cmd}` (under `nice -n 5`, 2 shared CPU cores, Cycles CPU; {total / 60:.0f} min).", "",
             f"Frame {W}x{H}, 5 objects ({build_name}) with sun shadows on a ground-plane road; outputs "
             f"{sorted(OUTPUTS)}. PSNR over the {int(mask.sum())} object and shadow pixels "
             f"({mask.mean():.1%} of the frame) of the composite over grey, against a {ref_samples}-sample "
             f"naive reference (whole road as shadow catcher, no denoise, no adaptive sampling, its own random "
             f"seed; rendered with the border region, which contains all measured pixels; {t_ref:.0f} s). "
             "Times are single runs except the default (median of 3); "
             "the machine is shared, so compare ratios; CPU time (all threads of the process) is the steadier "
             "measure of cost.", "",
             "| family | samples | denoise | region | bounces | time (s) | CPU (s) | PSNR (dB) |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['family']} | {r['samples']} | {'on' if r['denoise'] else 'off'} | "
                     f"{'border' if r['region'] else 'full'} | {r['bounces']} | {r['time_s']:.2f} | {r['cpu_s']:.2f} | "
                     f"{r['psnr_db']:.2f} |")
    lines += ["",
              f"- Time per frame at the job default ({Render().samples} samples, denoise, region): "
              f"**{default['time_s']:.2f} s** "
              f"(median of 3), {default['psnr_db']:.1f} dB.",
              f"  CPU time {default['cpu_s']:.2f} s (two threads: about half that in wall time on two "
              f"dedicated cores).",
              f"- Cheapest configuration with PSNR >= {TARGET_DB} dB (by CPU time): " +
              (f"{best['family']} {best['samples']} spp, denoise {'on' if best['denoise'] else 'off'}, "
               f"bounces {best['bounces']}: **{best['time_s']:.2f} s** wall, {best['cpu_s']:.2f} CPU s, "
               f"{best['psnr_db']:.1f} dB." if best else "none."),
              f"- Speedup over the naive full-frame render at >= {TARGET_DB} dB: **{speed}**.",
              f"- RSS over {frames} frames in one session (320x180, 1 spp, one object replaced every 10 frames): "
              f"{rss[0]:.0f} MB at frame 0, {base:.0f} MB at frame 10, {rss[-1]:.0f} MB at the end; "
              f"largest growth after frame 10: **{growth:+.1%}**.", "",
              f"![render benchmark](../../benchmarks/results/{png.name})", ""]
    write_text(png.with_suffix(".json"), json.dumps({"resolution": [W, H], "reference_samples": ref_samples,
                                                     "objects": build_name, "rows": rows, "rss_mb": rss},
                                                    indent=1))
    md = "\n".join(lines)
    write_text(RESULTS / ("render_sweep_quick.md" if args.quick else "render_sweep.md"), md)   # docs/render.md quotes it
    shutil.rmtree(tmp, ignore_errors=True)
    print("\n" + md)


# ---------------------------------------------------------------- issue 17: fair baseline, clusters
PAIR_DIMS = (4.5, 1.8, 1.5)


def pair_plans() -> dict[str, FramePlan]:
    """Two cars side by side 14 m ahead (one region) and the same two cars at opposite edges
    of the frame (two regions). At the edges the wide lens shows them more from the side and
    stretches them, so there they stand 18 m ahead: the two layouts then have the same content
    (object and shadow pixels within a few per cent, reported), and their cost difference is
    what the region layout costs."""
    side = [PlacedObject(11, "car", (14.0, 1.2, 0.0), 0.0, PAIR_DIMS, variant={"seed": 1}),
            PlacedObject(12, "car", (14.0, -1.2, 0.0), 0.0, PAIR_DIMS, variant={"seed": 5})]
    edges = [PlacedObject(11, "car", (18.0, 9.9, 0.0), 0.0, PAIR_DIMS, variant={"seed": 1}),
             PlacedObject(12, "car", (18.0, -9.9, 0.0), 0.0, PAIR_DIMS, variant={"seed": 5})]
    return {"side by side": FramePlan("side", 0.0, T.tolist(), side, SUN),
            "opposite edges": FramePlan("edges", 0.0, T.tolist(), edges, SUN)}


def region_area(info) -> int:
    return sum((r[2] - r[0]) * (r[3] - r[1]) for r in (info.get("regions") or []))


def fair(args):
    from blendgen.render import effects as fx

    W, H, ref_samples, cam, build, build_name, plan, tmp = _setup(args)
    t_start = time.perf_counter()
    reps = args.repeats

    # ---- 1. the reference: naive scene (whole road as catcher), many samples, own seed
    sess = warm_session(cam, build, plan, tmp, catch="ground")
    print(f"{W}x{H}, objects: {build_name}; reference {ref_samples} samples ...", flush=True)
    sess.scene.cycles.seed = 7919
    t_ref, info_ref, ref = run_config(sess, plan, Render(samples=ref_samples, denoise=False, adaptive_threshold=0),
                                      tmp / "ref.exr")
    sess.close()
    ref_img = display(ref)
    mask = _object_mask(ref, info_ref)
    print(f"reference: {t_ref:.0f} s wall, {int(mask.sum())} object+shadow pixels ({mask.mean():.1%})", flush=True)

    def row(name, r, t, info, p, extra=None):
        q = psnr(display(p), ref_img, mask)
        d = {"config": name, "samples": r.samples, "denoise": r.denoise, "time_s": t, "cpu_s": info["cpu_s"],
             "psnr_db": q, "regions": len(info.get("regions") or []) or "full", **(extra or {})}
        print(f"{name:28s} spp {r.samples:4d}  {t:7.2f} s  cpu {info['cpu_s']:7.2f} s  {q:6.2f} dB", flush=True)
        return d

    # ---- 2. blendgen at its defaults (Render()), and the clusters
    sess = warm_session(cam, build, plan, tmp)
    t, info, p = run_config(sess, plan, Render(), tmp / "b.exr", reps)
    blend = row("blendgen defaults", Render(), t, info, p, {"repeats": reps})
    target = blend["psnr_db"]
    # other operating points (sample counts) of blendgen, each against its own naive search
    points = {blend["samples"]: blend}
    for n in sorted(set(args.samples) - {blend["samples"]}):
        t, info, p = run_config(sess, plan, Render(samples=n), tmp / "b.exr", reps)
        points[n] = row("blendgen", Render(samples=n), t, info, p, {"repeats": reps})
    # the same frame with one region around all objects (before issue 17)
    over0 = fx.REGION_OVERHEAD_FRACTION
    fx.REGION_OVERHEAD_FRACTION = 1e12
    t, info, p = run_config(sess, plan, Render(), tmp / "b1.exr", reps)
    fx.REGION_OVERHEAD_FRACTION = over0
    blend_one = row("blendgen, one region", Render(), t, info, p, {"repeats": reps})

    pairs = pair_plans()
    small_reps = max(reps, 5)  # the pair and far-person renders are small: more runs, steadier medians
    cl = {}
    default_over = fx.REGION_OVERHEAD_FRACTION
    for name, pp in pairs.items():
        sess.render = Render(samples=1, denoise=False)
        sess.render_frame(pp, tmp / "warm.exr", OUTPUTS)  # build / move the two cars
        for mode, over in (("clustered", default_over), ("one region", 1e12)):
            if name == "side by side" and mode == "one region":
                continue  # side by side is one region either way
            fx.REGION_OVERHEAD_FRACTION = over
            t, info, p = run_config(sess, pp, Render(), tmp / f"pair_{mode}.exr", small_reps)
            content = int(((p["rgba"][..., 3] > 0.02) | (p["shadow_catcher"].min(axis=2) < 0.98)).sum())
            cl[(name, mode)] = {"time_s": t, "cpu_s": info["cpu_s"], "regions": info["regions"],
                                "area": region_area(info), "content_px": content, "passes": p}
            print(f"{name:15s} {mode:10s} regions {info['regions']}  cpu {info['cpu_s']:.2f} s", flush=True)
    fx.REGION_OVERHEAD_FRACTION = default_over
    a, b = cl[("opposite edges", "clustered")]["passes"], cl[("opposite edges", "one region")]["passes"]
    seen = (b["rgba"][..., 3] > 0.02) | (b["shadow_catcher"].min(axis=2) < 0.98)
    paste_db = psnr(display(a), display(b), seen)
    index_same = bool(np.array_equal(a["index"], b["index"]))
    # The fixed cost of one more render call: one far-off person (one small region) against
    # two far apart (two small regions); what a frame costs once (its passes, the EXR) cancels.
    person = (0.5, 0.6, 1.8)
    tiny = {k: FramePlan(f"tiny{k}", 0.0, T.tolist(),
                         [PlacedObject(21, "person", (60.0, 0.0, 0.0), 0.0, person),
                          PlacedObject(22, "person", (60.0, 25.0, 0.0), 0.0, person)][:k], SUN) for k in (1, 2)}
    info_t = {}
    for k, tp in tiny.items():
        sess.render = Render(samples=1, denoise=False)
        sess.render_frame(tp, tmp / "warm.exr", OUTPUTS)
        _, info_t[k], _ = run_config(sess, tp, Render(), tmp / "tiny.exr", small_reps)
    assert [len(info_t[k]["regions"]) for k in (1, 2)] == [1, 2], "the far persons must get one region each"
    sess.close()
    side = cl[("side by side", "clustered")]
    per_px = max(side["cpu_s"] - info_t[1]["cpu_s"], 1e-6) / max(side["area"] - region_area(info_t[1]), 1)
    call_cpu = (info_t[2]["cpu_s"] - info_t[1]["cpu_s"]) - per_px * (region_area(info_t[2]) - region_area(info_t[1]))
    overhead_px = max(call_cpu, 0.0) / per_px

    # ---- 3. the fair baseline: full frame, whole road as catcher, Blender's defaults + OIDN
    sess = warm_session(cam, build, plan, tmp, catch="ground", blender_defaults=True)
    defaults = sess.defaults

    def naive_at(n):
        r = Render(samples=n, denoise=True, region=False)
        t, info, p = run_config(sess, plan, r, tmp / "n.exr")
        return row("naive, Blender defaults", r, t, info, p)

    memo, finals = {}, {}
    for n, b in sorted(points.items()):
        found, _ = search_samples(naive_at, b["psnr_db"], 1, args.max_samples, memo)
        if found is not None and found["samples"] not in finals:
            r = Render(samples=found["samples"], denoise=True, region=False)
            walls, cpus = [found["time_s"]], [found["cpu_s"]]  # the search's run counts as the first
            for _ in range(reps - 1):
                t, info, p = run_config(sess, plan, r, tmp / "n.exr")
                walls.append(t)
                cpus.append(info["cpu_s"])
            finals[found["samples"]] = {**found, "config": "naive at the found samples",
                                        "time_s": statistics.median(walls), "cpu_s": statistics.median(cpus),
                                        "repeats": reps, "cpu_runs": cpus}
        b["naive"] = finals[found["samples"]] if found is not None else None
    tried = [memo[k] for k in sorted(memo)]
    final = blend["naive"]
    sess.close()

    # ---- 4. the ratio from interleaved pairs: blendgen, then the naive render at its found
    # count, each in a fresh session, so that both halves of a pair see the same load (other
    # jobs on a shared machine move CPU s by up to 1.6x from one minute to the next)
    pair_ratios = []
    for _ in range(args.pairs if final else 0):
        cpu = {}
        for kind in ("blendgen", "naive"):
            s_ = warm_session(cam, build, plan, tmp, catch="patches" if kind == "blendgen" else "ground",
                              blender_defaults=kind == "naive")
            r = Render() if kind == "blendgen" else Render(samples=final["samples"], denoise=True, region=False)
            cpu[kind] = run_config(s_, plan, r, tmp / "pair.exr")[1]["cpu_s"]
            s_.close()
        pair_ratios.append(cpu["naive"] / cpu["blendgen"])
        print(f"pair: blendgen {cpu['blendgen']:.2f} CPU s, naive {cpu['naive']:.2f} -> {pair_ratios[-1]:.1f}x", flush=True)
    total = time.perf_counter() - t_start

    # ---- report
    cmd = (".venv/bin/python benchmarks/render/bench_render.py" + (" --quick" if args.quick else "") +
           (f" --repeats {reps}" if reps != 3 else "") +
           (f" --samples {' '.join(map(str, args.samples))}" if args.samples != [12] else "") +
           (f" --pairs {args.pairs}" if args.pairs != 3 else ""))
    ratio = (final["cpu_s"] / blend["cpu_s"]) if final else None
    lines = [f"# Render cost: the fair baseline and clusters{' (quick)' if args.quick else ''}", "",
             f"Command: `{cmd}` (under `nice -n 5`; 2 CPU cores shared with other sessions' jobs, Cycles CPU; "
             f"{total / 60:.0f} min; {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}). CPU seconds = user + "
             "system time of the process (Blender renders in it, all its threads) around `render_frame`.", "",
             f"Frame {W}x{H}, 5 objects ({build_name}) with sun shadows on a ground-plane road; outputs "
             f"{sorted(OUTPUTS)}. PSNR over the {int(mask.sum())} object and shadow pixels ({mask.mean():.1%} of "
             f"the frame) of the composite over grey against a {ref_samples}-sample naive reference (no denoise, "
             f"own seed; {t_ref:.0f} s wall).", "",
             "## blendgen against the fair baseline", "",
             "Naive = full frame, the whole road as shadow catcher, Cycles' defaults for everything but the "
             "sample count (read from Blender's RNA: " + ", ".join(f"{k} {v}" for k, v in defaults.items()) +
             "), OIDN on. Its samples are searched: doubling from 1, then bisection, for the lowest count whose "
             f"PSNR reaches blendgen's ({target:.2f} dB).", "",
             "| configuration | samples | CPU (s) | wall (s) | PSNR (dB) | runs |", "|---|---|---|---|---|---|",
             f"| blendgen defaults (region clusters, catcher patches, adaptive, OIDN) | {blend['samples']} | "
             f"{blend['cpu_s']:.2f} | {blend['time_s']:.2f} | {blend['psnr_db']:.2f} | median of {reps} |",
             f"| blendgen, one region around all objects (before issue 17) | {blend_one['samples']} | "
             f"{blend_one['cpu_s']:.2f} | {blend_one['time_s']:.2f} | {blend_one['psnr_db']:.2f} | median of {reps} |"]
    for r in tried:
        lines.append(f"| naive search step | {r['samples']} | {r['cpu_s']:.2f} | {r['time_s']:.2f} | "
                     f"{r['psnr_db']:.2f} | 1 |")
    if final:
        lines.append(f"| **naive at the found count** | {final['samples']} | {final['cpu_s']:.2f} | "
                     f"{final['time_s']:.2f} | {final['psnr_db']:.2f} | median of {reps} |")
    lines += ["", (f"- Lowest naive sample count reaching {target:.2f} dB: **{final['samples']}**; blendgen is "
                   f"**{ratio:.1f}x cheaper in CPU seconds** ({final['cpu_s']:.2f} -> {blend['cpu_s']:.2f} s; "
                   f"wall {final['time_s'] / blend['time_s']:.1f}x)." if final else
                   f"- No naive sample count up to {args.max_samples} reached {target:.2f} dB.")]
    if pair_ratios:
        lines.append(f"- Interleaved pairs (blendgen, then the naive render at {final['samples']} spp, each in a fresh "
                     f"session, {len(pair_ratios)} times): CPU ratios "
                     f"{' / '.join(f'{x:.1f}x' for x in pair_ratios)}, median **{statistics.median(pair_ratios):.1f}x** "
                     "(both halves of a pair under the same load).")
    fit = fitted_naive_cpu(tried, target)
    if fit:
        lines.append(f"- The same against a straight-line fit of the naive CPU s over all {len(tried)} search renders "
                     f"({fit[2]:.1f} + {fit[3]:.2f} per sample), at {fit[0]:.2f} samples (interpolated in PSNR to "
                     f"{target:.2f} dB): {fit[1]:.2f} CPU s, **{fit[1] / blend['cpu_s']:.1f}x** (less exposed to one "
                     "noisy render; the search's PSNR steps are 0.1-0.4 dB apart).")
    if len(points) > 1:
        lines += ["", "Operating points: blendgen at other sample counts, each against the lowest naive count "
                  "reaching its PSNR (the same search, its renders shared):", "",
                  "| blendgen samples | PSNR (dB) | CPU (s) | naive samples | naive PSNR (dB) | naive CPU (s) | "
                  "CPU ratio |", "|---|---|---|---|---|---|---|"]
        for n, b in sorted(points.items()):
            nv = b["naive"]
            lines.append(f"| {n}{' (default)' if b is blend else ''} | {b['psnr_db']:.2f} | {b['cpu_s']:.2f} | " +
                         (f"{nv['samples']} | {nv['psnr_db']:.2f} | {nv['cpu_s']:.2f} | "
                          f"**{nv['cpu_s'] / b['cpu_s']:.1f}x** |" if nv else "none | | | |"))
    lines += ["", "## Clusters: two cars side by side vs at opposite edges", "",
              "At the edges the cars stand 18 m ahead instead of 14 m, so that both layouts show the same "
              "content (the wide lens stretches objects near the edges); the table gives the object and shadow "
              "pixels of each and the cost per content pixel as well.", "",
              "| layout | regions | pixels rendered | object + shadow px | CPU (s) | vs side by side | "
              "CPU per 10k object+shadow px | vs side by side |", "|---|---|---|---|---|---|---|---|"]
    for (name, mode), c in cl.items():
        per = 1e4 * c["cpu_s"] / max(c["content_px"], 1)
        per_side = 1e4 * side["cpu_s"] / max(side["content_px"], 1)
        lines.append(f"| {name}, {mode} | {len(c['regions'])} ({', '.join(str(r) for r in c['regions'])}) | "
                     f"{c['area']} | {c['content_px']} | {c['cpu_s']:.2f} | {c['cpu_s'] / side['cpu_s'] - 1:+.0%} | "
                     f"{per:.3f} | {per / per_side - 1:+.0%} |")
    lines += ["", f"- Opposite edges, clustered vs one region around both: PSNR of the pasted passes "
              f"{paste_db:.1f} dB over their object and shadow pixels, index pass "
              f"{'identical' if index_same else 'different'}.",
              (f"- One more render call's fixed cost: {call_cpu:.3f} CPU s" if call_cpu > 0 else
               "- One more render call's fixed cost: below what this measures") +
              f" (two far persons in two regions: {info_t[2]['cpu_s']:.3f} CPU s, one: {info_t[1]['cpu_s']:.3f} s, "
              f"less the second region's {region_area(info_t[2]) - region_area(info_t[1])} pixels at "
              f"{per_px * 1e6:.2f} CPU us per region pixel) -> {overhead_px:.0f} pixels, {overhead_px / (W * H):.4f} of "
              f"the frame; the whole second far person, call and pixels, cost "
              f"{info_t[2]['cpu_s'] - info_t[1]['cpu_s']:.3f} CPU s "
              f"(`effects.REGION_OVERHEAD_FRACTION` = {default_over}). Medians of {small_reps} runs.", "",
              f"- blendgen's 5-object frame rendered as {blend['regions']} region(s): {blend['cpu_s']:.2f} CPU s, "
              f"against {blend_one['cpu_s']:.2f} with one region around all objects "
              f"({blend['cpu_s'] / blend_one['cpu_s'] - 1:+.0%})."]
    md = "\n".join(lines)
    RESULTS.mkdir(parents=True, exist_ok=True)
    write_text(RESULTS / ("render_fair_quick.json" if args.quick else "render_fair.json"), json.dumps({
        "resolution": [W, H], "reference_samples": ref_samples, "blendgen": blend, "blendgen_one_region": blend_one,
        "naive_tried": tried, "operating_points": {str(n): {k: v for k, v in b.items()} for n, b in points.items()},
        "naive_final": final, "ratio_cpu": ratio, "naive_fit": fit, "defaults": defaults,
        "clusters": {f"{k[0]}, {k[1]}": {kk: vv for kk, vv in v.items() if kk != "passes"} for k, v in cl.items()},
        "paste_psnr_db": paste_db, "overhead_px": overhead_px, "pair_ratios": pair_ratios,
        "call_cpu_s": call_cpu}, indent=1, default=str))
    write_text(RESULTS / "render_fair_quick.md" if args.quick else DOC, md + "\n")   # a quick run is a smoke run
    shutil.rmtree(tmp, ignore_errors=True)
    print("\n" + md)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="640x360 (sweep: fewer configurations, 60 memory frames)")
    ap.add_argument("--ref-samples", type=int, default=None, help="reference samples (default 256; quick 128)")
    ap.add_argument("--repeats", type=int, default=3, help="runs per measured configuration (median)")
    ap.add_argument("--max-samples", type=int, default=256, help="upper end of the naive sample search")
    ap.add_argument("--samples", type=int, nargs="*", default=[12],
                    help="blendgen sample counts besides its default, each against its own naive search")
    ap.add_argument("--pairs", type=int, default=3,
                    help="interleaved blendgen / naive pairs for the load-robust ratio (0: none)")
    ap.add_argument("--sweep", action="store_true",
                    help="the samples/denoise/bounces sweep and the memory run instead (benchmarks/results/render_sweep.md)")
    ap.add_argument("--replot", type=Path, default=None, help="redraw the sweep plot from a results JSON and exit")
    args = ap.parse_args()
    if args.replot is not None:
        d = json.loads(args.replot.read_text())
        plot_results(d["rows"], d["rss_mb"], *d["resolution"], d["reference_samples"], args.replot.with_suffix(".png"))
        return
    (sweep if args.sweep else fair)(args)


if __name__ == "__main__":
    main()
