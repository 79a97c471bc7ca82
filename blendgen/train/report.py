"""The train-check's result as a markdown table (no torch)."""

from __future__ import annotations

import math

from blendgen.train.data import CLASS_OF_ID


def fmt(v: dict, key: str = "ap") -> str:
    m, lo, hi = v[key], v["lo"], v["hi"]
    if not math.isfinite(m):
        return "–"
    sign = "+" if key == "diff" and m > 0 else ""
    return f"{sign}{m:.3f} [{lo:.3f}, {hi:.3f}]"


def results_table(res: dict, *, train_images: int, test_images: int, command: str) -> str:
    s = res["summary"]
    cats = [str(c) for c in res["classes"]] + ["mean"]
    name = {str(c): CLASS_OF_ID[int(c)] for c in res["classes"]} | {"mean": "**class mean (mAP@0.5)**"}
    logs = res["log"]["fine-tuned"]
    lines = [f"Made by `{command}`.", "",
             f"{train_images} training images, {logs[0]['epochs']:g} epochs ({logs[0]['steps']} steps of "
             f"{logs[0]['batch']}), seeds {', '.join(str(lg['seed']) for lg in logs)}; {test_images} test images. "
             f"AP@0.5 per class (pycocotools); fine-tuned: mean over seeds. [95 % bootstrap interval over test "
             f"images, {s['n_boot']} draws; the difference is paired: the same draws for both.]", "",
             "| class | pretrained (no fine-tuning) | fine-tuned | per seed | fine-tuned - pretrained |",
             "|---|---|---|---|---|"]
    base = s["arms"].get("base")
    pair = s["pairs"].get("fine-tuned - base")
    for c in cats:
        ft = s["arms"]["fine-tuned"][c]
        lines.append(f"| {name[c]} | {fmt(base[c]) if base else '–'} | {fmt(ft)} | "
                     f"{', '.join(f'{v:.3f}' for v in ft['seeds'])} | {fmt(pair[c], 'diff') if pair else '–'} |")
    losses = ", ".join(f"{lg['loss_first']:.2f} -> {lg['loss_last']:.2f}" for lg in logs)
    lines += ["", f"Training loss (first -> last tenth of the steps, per seed): {losses}; "
                  f"{sum(lg['train_s'] for lg in logs):.0f} s of training in all."]
    return "\n".join(lines)
