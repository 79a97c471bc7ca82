"""Where blendgen's render error is, on the bench_render frame (issue 17).

Renders the 256-sample naive reference and blendgen's frame at the given sample counts, then
splits the squared error of the composite (the PSNR bench_render measures) into object pixels,
object edges and shadow pixels, and measures how much each pass costs: the frame with the
reference's alpha or the reference's shadow-catcher pass swapped in, and the catcher pass's
signed error on the shadow pixels (a bias stays put as samples grow; noise does not), and the
share of that error on shadow pixels no catcher patch covers (the faint sky occlusion farther
out than the patch margin, which then reads 1). With --ground the same frame with shadows
caught on the whole ground inside blendgen's regions.

    PYTHONPATH=$PWD nice -n 5 .venv/bin/python benchmarks/render/render_error_split.py [--samples 16 64] [--ground]
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout: its blendgen, benchmarks.common
from benchmarks.render import bench_render as B  # noqa: E402

from blendgen.job.schema import Render  # noqa: E402


def composite(rgba, catcher):
    return np.clip(rgba[..., :3] + (1.0 - rgba[..., 3:4]) * 0.5 * catcher, 0, 1) ** (1 / 2.2)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--samples", type=int, nargs="+", default=[16, 64])
    ap.add_argument("--ground", action="store_true", help="also catch shadows on the whole ground (in the regions)")
    args = ap.parse_args()
    W, H, ref_samples, cam, build, _, plan, tmp = B._setup(argparse.Namespace(quick=False, ref_samples=None))

    sess = B.warm_session(cam, build, plan, tmp, catch="ground")
    sess.scene.cycles.seed = 7919  # bench_render's reference
    _, info_ref, ref = B.run_config(sess, plan, Render(samples=ref_samples, denoise=False, adaptive_threshold=0),
                                    tmp / "ref.exr")
    sess.close()
    ref_img, mask = B.display(ref), B._object_mask(ref, info_ref)
    a_ref = ref["rgba"][..., 3]
    solid = (a_ref > 0.5).astype(np.uint8)
    edge = mask & ((cv2.dilate(solid, np.ones((3, 3))) - cv2.erode(solid, np.ones((3, 3)))) > 0)
    obj = mask & (a_ref > 0.02) & ~edge
    shadow = mask & ~obj & ~edge
    print(f"{W}x{H}; measured pixels {mask.sum()}: objects {obj.sum()}, object edges {edge.sum()}, "
          f"shadows {shadow.sum()}")

    # Shadow pixels outside every catcher patch (projected patch polygons; patches mode only).
    from blendgen.render import effects as fx

    T = np.asarray(plan.T_world_cam, float)
    covered = np.zeros(mask.shape, np.uint8)
    for poly in fx.catcher_patches(plan.objects, fx.shadow_light_direction(plan.lighting)):
        uv, _ = cam.project_world(T, poly)
        cv2.fillPoly(covered, [np.rint(uv).astype(np.int32)], 1)
    off_patch = shadow & ~covered.astype(bool)

    sess = B.warm_session(cam, build, plan, tmp)
    rows = []
    for mode in ("patches", "ground") if args.ground else ("patches",):
        sess.catch_shadows_on = mode
        for n in args.samples:
            _, info, p = B.run_config(sess, plan, Render(samples=n), tmp / "b.exr")
            img = B.display(p)
            err = ((img - ref_img) ** 2).mean(axis=2)
            share = {k: err[m].sum() / err[mask].sum() for k, m in (("obj", obj), ("edge", edge), ("shadow", shadow))}
            alpha_swapped = p["rgba"].copy()
            alpha_swapped[..., 3] = a_ref
            sc_err = (p["shadow_catcher"] - ref["shadow_catcher"]).mean(axis=2)
            bias = sc_err[shadow]
            off = (sc_err[off_patch] ** 2).sum() / (bias ** 2).sum() if mode == "patches" else 0.0
            rows.append((mode, n, B.psnr(img, ref_img, mask), share,
                         B.psnr(composite(alpha_swapped, p["shadow_catcher"]), ref_img, mask),
                         B.psnr(composite(p["rgba"], ref["shadow_catcher"]), ref_img, mask),
                         float(bias.mean()), float(np.sqrt((bias ** 2).mean())), off, info["cpu_s"]))
    sess.close()

    print("\n| catch on | spp | PSNR (dB) | SSE objects / edges / shadows | ref alpha | ref catcher | "
          "catcher error on shadows: signed / rms | of it off the patches | CPU s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for mode, n, q, sh, qa, qc, b, rms, off, cpu in rows:
        print(f"| {mode} | {n} | {q:.2f} | {sh['obj']:.0%} / {sh['edge']:.0%} / {sh['shadow']:.0%} | "
              f"{qa - q:+.2f} dB | {qc - q:+.2f} dB | {b:+.4f} / {rms:.4f} | {off:.0%} | {cpu:.2f} |")
    print(f"\nshadow pixels off the patches: {off_patch.sum()} of {shadow.sum()}")
    print(f"\n(one render each; CPU s are noisy, PSNR is deterministic; median CPU "
          f"{statistics.median(r[-1] for r in rows):.2f} s)")


if __name__ == "__main__":
    main()
