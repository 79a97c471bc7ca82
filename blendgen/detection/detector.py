"""An ONNX YOLOX detector run through onnxruntime (COCO-pretrained, e.g. yolox_nano.onnx).

Pre-processing as YOLOX >= 0.1.1 exports expect: letterbox into the square input with
value 114 at the top-left, BGR 0-255, no normalisation. Post-processing: the raw head
(cx, cy, log w, log h, objectness, 80 class scores per anchor point) is decoded with the
grid offsets and strides 8/16/32, score = objectness * class score, class-wise NMS.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from blendgen.errors import UserError

# The 80 COCO classes in YOLOX's output order -> COCO category ids.
COCO80_TO_ID = [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22, 23, 24, 25,
                27, 28, 31, 32, 33, 34, 35, 36, 37, 38, 39, 40, 41, 42, 43, 44, 46, 47, 48, 49, 50, 51,
                52, 53, 54, 55, 56, 57, 58, 59, 60, 61, 62, 63, 64, 65, 67, 70, 72, 73, 74, 75, 76, 77,
                78, 79, 80, 81, 82, 84, 85, 86, 87, 88, 89, 90]
STRIDES = (8, 16, 32)
# YOLOX-Nano (Apache-2.0), shipped inside the package (models/ with its LICENSE and NOTICE):
# nothing is downloaded. Its sha256 is checked before use (analysis.objects.load_detector).
BUNDLED_MODEL = Path(__file__).with_name("models") / "yolox_nano.onnx"
BUNDLED_SHA256 = "c789161ed43c8269fcd4e67c67eeeb4e80c622da2eb296a20bc6007bd18a0b7d"


class YoloxDetector:
    def __init__(self, model: Path, *, score_min: float = 0.01, nms_iou: float = 0.65,
                 category_ids: set[int] | None = None, threads: int | None = None):
        import onnxruntime as ort

        model = Path(model)
        self.model_path = model
        if not model.is_file():
            raise UserError("detector model not found", where=str(model))
        opts = ort.SessionOptions()
        if threads:
            opts.intra_op_num_threads = threads
        try:
            self.session = ort.InferenceSession(str(model), opts, providers=["CPUExecutionProvider"])
        except Exception as e:  # onnxruntime raises its own exception types for bad files
            raise UserError(f"not a loadable ONNX model ({e})", where=str(model)) from None
        inp = self.session.get_inputs()[0]
        self.input_name = inp.name
        if len(inp.shape) != 4 or not all(isinstance(s, int) for s in inp.shape[2:]):
            raise UserError(f"expected a fixed NCHW image input, got {inp.shape}", where=str(model))
        self.size = (int(inp.shape[2]), int(inp.shape[3]))  # (h, w)
        out = self.session.get_outputs()[0].shape
        n_expected = sum((self.size[0] // s) * (self.size[1] // s) for s in STRIDES)
        if out[-1] != 85 or (isinstance(out[1], int) and out[1] != n_expected):
            raise UserError(f"output {out} is not a YOLOX COCO head ([1, {n_expected}, 85])", where=str(model))
        self.grid, self.stride = _grids(self.size)
        self.score_min, self.nms_iou = score_min, nms_iou
        self.category_ids = category_ids

    def preprocess(self, bgr: np.ndarray) -> tuple[np.ndarray, float]:
        padded, r = letterbox(bgr, self.size)
        return np.ascontiguousarray(padded.transpose(2, 0, 1)[None], dtype=np.float32), r

    def decode(self, raw: np.ndarray, ratio: float) -> list[dict]:
        """raw: (N, 85) head output -> detections in the original image's pixels."""
        return decode(raw, ratio, self.grid, self.stride, self.score_min, self.nms_iou, self.category_ids)

    def __call__(self, bgr: np.ndarray) -> list[dict]:
        """Detections on one BGR uint8 image: [{bbox [x,y,w,h], score, category_id}]."""
        x, r = self.preprocess(bgr)
        raw = self.session.run(None, {self.input_name: x})[0][0]
        if not np.isfinite(raw).all():
            raw = np.nan_to_num(raw, nan=-1e9, posinf=1e9, neginf=-1e9)
        dets = self.decode(raw.astype(np.float64), r)
        H, W = bgr.shape[:2]
        for d in dets:  # clip to the image, as labels never leave it
            x, y, w, h = d["bbox"]
            x0, y0, x1, y1 = max(x, 0.0), max(y, 0.0), min(x + w, W), min(y + h, H)
            d["bbox"] = [x0, y0, max(x1 - x0, 0.0), max(y1 - y0, 0.0)]
        return [d for d in dets if d["bbox"][2] > 0 and d["bbox"][3] > 0]


def letterbox(bgr: np.ndarray, size: tuple[int, int]) -> tuple[np.ndarray, float]:
    """The image scaled to fit (h, w) `size`, at the top left, padded with 114; and the scale."""
    h, w = bgr.shape[:2]
    r = min(size[0] / h, size[1] / w)
    resized = cv2.resize(bgr, (int(w * r), int(h * r)), interpolation=cv2.INTER_LINEAR)
    padded = np.full((size[0], size[1], 3), 114, np.uint8)
    padded[:resized.shape[0], :resized.shape[1]] = resized
    return padded, r


def decode(raw: np.ndarray, ratio: float, grid: np.ndarray, stride: np.ndarray, score_min: float,
           nms_iou: float, category_ids: set[int] | None = None, max_dets: int | None = None) -> list[dict]:
    """A YOLOX head's (N, 85) output (sigmoid scores) -> detections [x, y, w, h] in the original
    image's pixels (divided by the letterbox `ratio`), class-wise NMS, best first."""
    xy = (raw[:, :2] + grid) * stride
    wh = np.exp(np.minimum(raw[:, 2:4], 20.0)) * stride  # clamp: exp overflow on junk input
    cls = np.argmax(raw[:, 5:], axis=1)
    score = raw[:, 4] * raw[np.arange(len(raw)), 5 + cls]
    keep = score >= score_min
    if category_ids is not None:
        cat = np.asarray(COCO80_TO_ID)[cls]
        keep &= np.isin(cat, list(category_ids))
    xy, wh, cls, score = xy[keep] / ratio, wh[keep] / ratio, cls[keep], score[keep]
    boxes = np.concatenate([xy - wh / 2, wh], axis=1)  # x, y, w, h
    if len(boxes) == 0:
        return []
    idx = cv2.dnn.NMSBoxesBatched(boxes.tolist(), score.tolist(), cls.tolist(), score_min, nms_iou)
    idx = np.asarray(idx, dtype=int).ravel()
    idx = idx[np.argsort(-score[idx], kind="stable")][:max_dets]
    return [{"bbox": [float(v) for v in boxes[i]], "score": float(score[i]),
             "category_id": COCO80_TO_ID[int(cls[i])]} for i in idx]


def _grids(size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    grids, strides = [], []
    for s in STRIDES:
        hs, ws = size[0] // s, size[1] // s
        yv, xv = np.meshgrid(np.arange(hs), np.arange(ws), indexing="ij")
        grids.append(np.stack([xv, yv], axis=2).reshape(-1, 2))
        strides.append(np.full((hs * ws, 1), s))
    return np.concatenate(grids).astype(np.float64), np.concatenate(strides).astype(np.float64)
