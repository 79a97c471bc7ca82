"""`blendgen train-check`: what is a training set worth to a detector? (needs torch)

Fine-tune the COCO-pretrained YOLOX-Nano (the bundled ONNX, rebuilt by blendgen.train.yolox)
on the training images, once per seed, and score it on a real labelled test set: AP@0.5 per
class with pycocotools, the mean over seeds, 95 % bootstrap intervals over test images, and
the paired difference to the pretrained model without fine-tuning (same test images).

Schedule: SGD with Nesterov momentum 0.9, learning rate 0.01 per 64 images (YOLOX's), a linear
warm-up over the first fifth of the steps (at most 50) and a cosine decay to 5 %; weight decay
5e-4 on convolution weights; letterboxed 416 x 416 inputs as the ONNX model takes them,
horizontal flips. BatchNorm is un-folded from the training images' statistics first
(yolox.unfold_batchnorm). The first convolution stays frozen: it sees raw 0-255 pixel values
(the export has no input normalisation), so its weight gradients are ~100x every other
layer's, and one step at the schedule's rate moved it far enough to take AP@0.5 on real photos
from 0.4-0.9 to 0 (its BatchNorm, after it, is trained). The number of images (`images`: a seeded subset) and of epochs are
the caller's: arms compared with each other must use the same.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from blendgen.errors import UserError
from blendgen.train.data import Sample, load_image
from blendgen.train.evaluate import bootstrap, cocoeval_ap50, match_records

BASE_LR_PER_64 = 0.01
WEIGHT_DECAY = 5e-4
UNFOLD_IMAGES = 64
EVAL_SCORE_MIN = 0.001  # COCO-style evaluation: every detection, AP integrates over scores
NMS_IOU = 0.65


def subset(samples: list[Sample], n: int | None, seed: int) -> list[Sample]:
    """`n` samples drawn without replacement with `seed` (all when n is None or too large)."""
    if n is None or n >= len(samples):
        return list(samples)
    pick = np.sort(np.random.default_rng(seed).permutation(len(samples))[:n])
    return [samples[i] for i in pick]


def fine_tune(model_path: Path, samples: list[Sample], *, seed: int, epochs: float, batch: int = 8,
              size: int = 416, progress=None):
    """The pretrained model fine-tuned on `samples`; returns (model in eval mode, log dict)."""
    import torch

    from blendgen.train.loss import yolox_loss
    from blendgen.train.yolox import load_onnx, unfold_batchnorm

    if not samples:
        raise UserError("no training images")
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    model = load_onnx(model_path)
    unfold = [load_image(s, size)[0] for s in samples[:UNFOLD_IMAGES]]
    unfold_batchnorm(model, torch.from_numpy(np.stack(unfold)))
    model.backbone.stem.conv.conv.weight.requires_grad_(False)
    params = [(n, p) for n, p in model.named_parameters() if p.requires_grad]
    decay = [p for n, p in params if n.endswith("conv.weight") or n.endswith("pred.weight")]
    other = [p for n, p in params if not (n.endswith("conv.weight") or n.endswith("pred.weight"))]
    lr = BASE_LR_PER_64 * batch / 64
    opt = torch.optim.SGD([{"params": decay, "weight_decay": WEIGHT_DECAY}, {"params": other, "weight_decay": 0.0}],
                          lr=lr, momentum=0.9, nesterov=True)
    steps_per_epoch = math.ceil(len(samples) / batch)
    steps = max(1, round(steps_per_epoch * epochs))
    warm = min(50, max(1, steps // 5))
    grid, stride = model.grids(size, size)
    model.train()
    losses, t0 = [], time.perf_counter()
    order: list[int] = []
    for step in range(steps):
        if len(order) < batch:
            order += list(rng.permutation(len(samples)))
        idx, order = order[:batch], order[batch:]
        f = lr * (step + 1) / warm if step < warm else \
            lr * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * (step - warm) / max(1, steps - warm))))
        for g in opt.param_groups:
            g["lr"] = f
        xs, targets = [], []
        for i in idx:
            x, boxes, cls, ign = load_image(samples[i], size, flip=bool(rng.random() < 0.5))
            xs.append(x)
            targets.append((boxes, cls, ign))
        out = model(torch.from_numpy(np.stack(xs)))
        loss, parts = yolox_loss(out, grid, stride, targets)
        if not torch.isfinite(loss):
            raise FloatingPointError(f"training loss is {loss.item()} at step {step} (seed {seed})")
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
        if progress:
            progress(step + 1, steps, float(loss))
    model.eval()
    return model, {"steps": steps, "batch": batch, "epochs": epochs, "images": len(samples), "lr": lr,
                   "loss_first": float(np.mean(losses[:max(1, steps // 10)])),
                   "loss_last": float(np.mean(losses[-max(1, steps // 10):])),
                   "train_s": round(time.perf_counter() - t0, 1)}


def predict(model, samples: list[Sample], category_ids, size: int = 416, batch: int = 16) -> list[list[dict]]:
    """Detections of `model` (YoloxNano) on each sample's image, in its pixels."""
    import torch

    from blendgen.detection.detector import decode

    grid, stride = (t.numpy().astype(np.float64) for t in model.grids(size, size))
    out = []
    model.eval()
    for k in range(0, len(samples), batch):
        chunk = samples[k:k + batch]
        xs, ratios = [], []
        for s in chunk:
            x, _, _, _ = load_image(s, size)
            xs.append(x)
            ratios.append(min(size / s.height, size / s.width))
        with torch.no_grad():
            raw = model.predict(torch.from_numpy(np.stack(xs))).numpy().astype(np.float64)
        for r, ratio in zip(raw, ratios):
            out.append(decode(r, ratio, grid, stride, EVAL_SCORE_MIN, NMS_IOU, set(category_ids), max_dets=100))
    return out


def train_check(train: list[Sample], test: list[Sample], *, model_path: Path, seeds=(0, 1, 2), epochs: float = 5,
                images: int | None = None, batch: int = 8, size: int = 416, n_boot: int = 1000,
                progress=None, base: bool = True) -> dict:
    """Fine-tune per seed and score; returns {"classes", "log", "records", "cocoeval", "summary"}."""
    import torch  # noqa: F401 - a clear error before any work when torch is missing

    from blendgen.train.yolox import load_onnx

    cats = sorted({int(c) for s in test for c in s.category_ids})
    if not cats:
        raise UserError("the test set has no labelled objects of blendgen's classes")
    records, coco, log = {}, {}, {}
    if base:
        model = load_onnx(model_path).eval()
        dets = predict(model, test, cats, size)
        records["base"] = [match_records(test, dets, cats)]
        coco["base"] = [cocoeval_ap50(test, dets, cats)]
    tuned_recs, tuned_coco, logs = [], [], []
    for seed in seeds:
        chosen = subset(train, images, seed)
        model, lg = fine_tune(model_path, chosen, seed=seed, epochs=epochs, batch=batch, size=size,
                              progress=(lambda a, b, l, s=seed: progress(s, a, b, l)) if progress else None)
        dets = predict(model, test, cats, size)
        tuned_recs.append(match_records(test, dets, cats))
        tuned_coco.append(cocoeval_ap50(test, dets, cats))
        logs.append({"seed": seed, **lg})
    records["fine-tuned"] = tuned_recs
    coco["fine-tuned"] = tuned_coco
    log["fine-tuned"] = logs
    summary = bootstrap(records, cats, len(test), n_boot=n_boot,
                        pairs=[("fine-tuned", "base")] if base else [])
    return {"classes": cats, "log": log, "records": records, "cocoeval": coco, "summary": summary}
