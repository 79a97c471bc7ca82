"""The training check: YOLOX-Nano rebuilt in PyTorch from the bundled ONNX, its loss, the
AP@0.5 with bootstrap intervals, and `blendgen train-check` end to end on a few real photos.
The torch tests run when torch is installed (an optional extra); the others always."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from blendgen.detection.detector import BUNDLED_MODEL
from blendgen.train.data import Sample
from blendgen.train.evaluate import bootstrap, cocoeval_ap50, match_records
from blendgen.train.onnx_weights import read_convs

DATA = Path(os.environ.get("BLENDGEN_SHARED_DATA", Path(__file__).resolve().parents[1].parent / "shared" / "data"))
LABELLED = DATA / "real" / "labelled" / "highway_objects_cc_by"


def test_onnx_reader_finds_the_113_convolutions():
    convs = read_convs(BUNDLED_MODEL)
    assert len(convs) == 113
    assert convs[0].weight.shape == (16, 12, 3, 3) and convs[0].attrs["strides"] == [1, 1]
    assert convs[1].attrs["group"] == 16 and convs[1].attrs["strides"] == [2, 2]  # depthwise, stride 2
    # the last level: class prediction, then the box branch (two separable convs), box, objectness
    assert [c.weight.shape[0] for c in convs[-7:]] == [80, 64, 64, 64, 64, 4, 1]
    assert all(c.bias is not None and np.isfinite(c.weight).all() for c in convs)


def _random_set(rng, n=30, cats=(3, 1)):
    samples, dets = [], []
    for k in range(n):
        boxes, cids, dd = [], [], []
        for c in cats:
            for _ in range(rng.integers(0, 3)):
                x, y = rng.uniform(0, 80, 2)
                w, h = rng.uniform(5, 20, 2)
                boxes.append([x, y, x + w, y + h])
                cids.append(c)
                if rng.random() < 0.7:  # found, a little off
                    dd.append({"bbox": [x + rng.normal(0, 2), y + rng.normal(0, 2), w, h], "score": rng.random(),
                               "category_id": c})
        for _ in range(rng.integers(0, 3)):  # false detections
            dd.append({"bbox": list(rng.uniform(0, 80, 2)) + [10.0, 10.0], "score": rng.random(),
                       "category_id": int(rng.choice(cats))})
        ign = np.array([[0, 0, 8, 8]], float) if k % 5 == 0 else np.zeros((0, 4))
        samples.append(Sample(Path(f"{k}.png"), 100, 100, np.array(boxes, float).reshape(-1, 4),
                              np.array(cids, int), ign))
        dets.append(dd)
    return samples, dets


def test_ap_from_match_records_equals_pycocotools():
    samples, dets = _random_set(np.random.default_rng(0))
    coco = cocoeval_ap50(samples, dets, [1, 3])
    recs = match_records(samples, dets, [1, 3])
    res = bootstrap({"a": [recs]}, [1, 3], len(samples), n_boot=200)
    for c in (1, 3):
        assert res["arms"]["a"][str(c)]["ap"] == pytest.approx(coco[c], abs=1e-9)
        row = res["arms"]["a"][str(c)]
        assert row["lo"] <= row["ap"] <= row["hi"] and row["hi"] - row["lo"] > 0.01
    # the paired difference of an arm with itself is exactly zero in every draw
    same = bootstrap({"a": [recs], "b": [recs]}, [1, 3], len(samples), n_boot=50, pairs=[("a", "b")])
    assert same["pairs"]["a - b"]["mean"] == {"diff": 0.0, "lo": 0.0, "hi": 0.0}


def test_train_check_without_torch_says_how_to_get_it(monkeypatch, capsys):
    from blendgen import cli

    monkeypatch.setitem(sys.modules, "torch", None)  # as if not installed
    rc = cli.main(["train-check", "x", "--test", "t", "--test-labels", "l", "--test-format", "yolo"])
    assert rc == 2 and "pip install 'blendgen[train]'" in capsys.readouterr().err


# ------------------------------------------------------------------------------------- torch

def test_rebuilt_model_matches_the_onnx_and_unfolds_batchnorm():
    torch = pytest.importorskip("torch")
    from blendgen.detection.detector import YoloxDetector
    from blendgen.train.yolox import load_onnx, unfold_batchnorm

    det = YoloxDetector(BUNDLED_MODEL)
    rng = np.random.default_rng(1)
    yy, xx = np.mgrid[0:360, 0:640]
    imgs = [np.clip(np.stack([xx * 0.3 + 20 * k, yy * 0.5, 128 + 60 * np.sin(xx / 30.0)], 2)
                    + rng.normal(0, 20, (360, 640, 3)), 0, 255).astype(np.uint8) for k in range(3)]
    x = np.concatenate([det.preprocess(im)[0] for im in imgs])
    ref = np.concatenate([det.session.run(None, {det.input_name: x[k:k + 1]})[0] for k in range(len(x))])
    model = load_onnx(BUNDLED_MODEL).eval()
    with torch.no_grad():
        out = model.predict(torch.from_numpy(x)).numpy()
    assert np.abs(out - ref).max() < 1e-3 and np.abs(out[..., 4:] - ref[..., 4:]).max() < 1e-4
    unfold_batchnorm(model, torch.from_numpy(x))
    bn = model.backbone.stage3[1].merge.bn
    assert not torch.allclose(bn.running_var, torch.ones_like(bn.running_var))  # real statistics now
    model.eval()
    with torch.no_grad():
        out2 = model.predict(torch.from_numpy(x)).numpy()
    assert np.abs(out2 - ref).max() < 1e-3  # the same function


def test_loss_assigns_anchors_to_boxes_and_ignores_regions():
    torch = pytest.importorskip("torch")
    from blendgen.train.loss import simota, yolox_loss
    from blendgen.train.yolox import YoloxNano

    model = YoloxNano()
    grid, stride = model.grids(128, 128)
    centres = (grid + 0.5) * stride
    N = grid.shape[0]
    out = torch.zeros(1, N, 85)
    gt = torch.tensor([[20.0, 30.0, 60.0, 90.0]])
    raw = torch.zeros(N, 4)
    from blendgen.train.loss import decode_boxes
    fg, gt_of, iou = simota(out[0, :, 5:], out[0, :, 4:5], decode_boxes(raw, grid, stride), centres, stride, gt,
                            torch.tensor([2]), 80)
    assert fg.sum() >= 1 and (gt_of == 0).all()
    c = centres[fg]
    assert ((c[:, 0] > 20) & (c[:, 0] < 60) & (c[:, 1] > 30) & (c[:, 1] < 90)).all()
    # an ignore region over half the image removes those anchors' objectness loss
    empty = (np.zeros((0, 4)), np.zeros(0, int), np.zeros((0, 4)))
    ign = (np.zeros((0, 4)), np.zeros(0, int), np.array([[0.0, 0.0, 64.0, 128.0]]))
    out = torch.full((1, N, 85), 2.0)  # confident everywhere: every background anchor costs
    l_all, _ = yolox_loss(out, grid, stride, [empty])
    l_ign, _ = yolox_loss(out, grid, stride, [ign])
    assert 0.3 < float(l_ign) / float(l_all) < 0.7


@pytest.mark.data
def test_train_check_runs_end_to_end_on_a_few_real_photos(tmp_path):
    pytest.importorskip("torch")
    if not LABELLED.is_dir():
        pytest.skip(f"needs {LABELLED}")
    # a training source as `blendgen import images --labels` makes it, and a small test split
    train_imgs, test_imgs = tmp_path / "train", tmp_path / "test"
    for split, dst, n in (("train", train_imgs, 6), ("test", test_imgs, 6)):
        (dst / "images").mkdir(parents=True)
        (dst / "labels").mkdir()
        for p in sorted((LABELLED / split / "images").glob("*.jpg"))[:n]:
            os.symlink(p, dst / "images" / p.name)
            os.symlink(LABELLED / split / "labels" / (p.stem + ".txt"), dst / "labels" / (p.stem + ".txt"))
        (dst / "data.yaml").write_text((LABELLED / "data.yaml").read_text())
    cli = [sys.executable, "-m", "blendgen.cli"]
    r = subprocess.run(cli + ["import", "images", str(train_imgs / "images"), str(tmp_path / "rec"), "--labels",
                              str(train_imgs / "labels"), "--label-format", "yolo", "--no-progress"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    r = subprocess.run(cli + ["train-check", str(tmp_path / "rec"), "--test", str(test_imgs / "images"),
                              "--test-labels", str(test_imgs / "labels"), "--test-format", "yolo", "--seeds", "0",
                              "--epochs", "1", "--batch", "3", "--bootstrap", "50", "--out", str(tmp_path / "ev")],
                       capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-3000:]
    res = json.loads((tmp_path / "ev" / "train_check.json").read_text())
    mean = res["summary"]["arms"]["fine-tuned"]["mean"]
    assert np.isfinite(mean["ap"]) and 0.0 <= mean["ap"] <= 1.0
    assert np.isfinite(res["summary"]["arms"]["base"]["mean"]["ap"])
    assert res["log"]["fine-tuned"][0]["steps"] == 2 and np.isfinite(res["log"]["fine-tuned"][0]["loss_last"])
    assert "class mean (mAP@0.5)" in (tmp_path / "ev" / "train_check.md").read_text()
