"""The YOLOX training loss with SimOTA label assignment (needs torch).

Per image, anchor points whose centre lies in a ground-truth box or within 2.5 strides of its
centre are candidates. Each box takes its k cheapest candidates, k = the sum of its 10 best
IoUs (at least 1), cost = class BCE (on sqrt(class x objectness) scores) + 3 x -log IoU, with
a large penalty outside "box and centre"; a candidate claimed by two boxes goes to the cheaper.
Losses, summed and divided by the number of assigned anchors: 5 x (1 - IoU^2) for the boxes,
BCE for objectness (target: assigned) over every anchor, BCE for the classes of assigned
anchors against one-hot x the IoU of their prediction.

Ignore regions (COCO iscrowd, KITTI DontCare, uncertain real detections): an unassigned anchor
whose centre lies in one gets no objectness loss, so a real object nobody labelled is neither
taught as object nor as background.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

CENTER_RADIUS = 2.5
TOPK_IOU = 10
IOU_WEIGHT = 5.0


def box_iou_xyxy(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    lt = torch.maximum(a[:, None, :2], b[None, :, :2])
    rb = torch.minimum(a[:, None, 2:], b[None, :, 2:])
    inter = (rb - lt).clamp(min=0).prod(2)
    area_a = (a[:, 2:] - a[:, :2]).clamp(min=0).prod(1)
    area_b = (b[:, 2:] - b[:, :2]).clamp(min=0).prod(1)
    return inter / (area_a[:, None] + area_b[None, :] - inter + 1e-9)


def decode_boxes(raw: torch.Tensor, grid: torch.Tensor, stride: torch.Tensor) -> torch.Tensor:
    """(N, 4) raw regression -> (N, 4) boxes x0 y0 x1 y1 in input pixels."""
    c = (raw[:, :2] + grid) * stride
    wh = torch.exp(raw[:, 2:4].clamp(max=10.0)) * stride
    return torch.cat([c - wh / 2, c + wh / 2], 1)


def simota(cls_logit, obj_logit, pred_boxes, centres, stride, gt_boxes, gt_cls, num_classes):
    """(fg mask (N,), matched gt index per fg anchor, IoU of each fg prediction with its gt)."""
    N = centres.shape[0]
    gt_c = (gt_boxes[:, :2] + gt_boxes[:, 2:]) / 2
    in_box = ((centres[None] > gt_boxes[:, None, :2]) & (centres[None] < gt_boxes[:, None, 2:])).all(2)
    r = CENTER_RADIUS * stride[:, 0]
    in_ctr = ((centres[None] - gt_c[:, None]).abs() < r[None, :, None]).all(2)
    cand = (in_box | in_ctr).any(0)
    fg = torch.zeros(N, dtype=torch.bool, device=centres.device)
    if not cand.any():
        return fg, torch.zeros(0, dtype=torch.long), torch.zeros(0)
    both = (in_box & in_ctr)[:, cand]
    ious = box_iou_xyxy(gt_boxes, pred_boxes[cand])
    iou_cost = -torch.log(ious + 1e-8)
    with torch.no_grad():
        p = (cls_logit[cand].sigmoid() * obj_logit[cand].sigmoid()).sqrt()  # (C, K)
        onehot = F.one_hot(gt_cls, num_classes).float()  # (M, K)
        pe = p[None].expand(len(gt_cls), -1, -1)
        cls_cost = F.binary_cross_entropy(pe.clamp(1e-6, 1 - 1e-6), onehot[:, None].expand_as(pe),
                                          reduction="none").sum(-1)
    cost = cls_cost + 3.0 * iou_cost + 1e5 * (~both).float()
    k = ious.topk(min(TOPK_IOU, ious.shape[1]), dim=1).values.sum(1).int().clamp(min=1)
    match = torch.zeros_like(cost, dtype=torch.bool)
    for g in range(len(gt_cls)):
        idx = cost[g].topk(int(min(k[g], cost.shape[1])), largest=False).indices
        match[g, idx] = True
    multi = match.sum(0) > 1
    if multi.any():
        best = cost[:, multi].argmin(0)
        match[:, multi] = False
        match[best, multi.nonzero()[:, 0]] = True
    taken = match.any(0)
    cand_idx = cand.nonzero()[:, 0]
    fg[cand_idx[taken]] = True
    gt_of = match[:, taken].float().argmax(0)
    return fg, gt_of, ious[gt_of, taken.nonzero()[:, 0]]


def yolox_loss(out: torch.Tensor, grid: torch.Tensor, stride: torch.Tensor, targets: list[tuple]) -> tuple:
    """out: (B, N, 5 + C) logits (YoloxNano.forward); targets: per image (boxes (M, 4) xyxy in input
    pixels, class indices (M,), ignore boxes (K, 4)). Returns (loss, parts dict)."""
    B, N, D = out.shape
    C = D - 5
    centres = (grid + 0.5) * stride
    iou_l, obj_l, cls_l, n_fg = out.new_zeros(()), out.new_zeros(()), out.new_zeros(()), 0
    for b in range(B):
        o = out[b]
        boxes = decode_boxes(o[:, :4], grid, stride)
        gt_boxes, gt_cls, ign = (torch.as_tensor(t, dtype=out.dtype if k != 1 else torch.long)
                                 for k, t in enumerate(targets[b]))
        obj_target = torch.zeros(N, dtype=out.dtype)
        weight = torch.ones(N, dtype=out.dtype)
        if len(gt_cls):
            fg, gt_of, pred_iou = simota(o[:, 5:], o[:, 4:5], boxes.detach(), centres, stride, gt_boxes, gt_cls, C)
            if fg.any():
                n_fg += int(fg.sum())
                obj_target[fg] = 1.0
                iou = torch.diag(box_iou_xyxy(boxes[fg], gt_boxes[gt_of])) if fg.sum() else boxes.new_zeros(0)
                iou_l = iou_l + (1.0 - iou ** 2).sum()
                cls_t = F.one_hot(gt_cls[gt_of], C).to(out.dtype) * pred_iou.detach()[:, None]
                cls_l = cls_l + F.binary_cross_entropy_with_logits(o[fg, 5:], cls_t, reduction="sum")
        else:
            fg = torch.zeros(N, dtype=torch.bool)
        if len(ign):
            inside = ((centres[None] > ign[:, None, :2]) & (centres[None] < ign[:, None, 2:])).all(2).any(0)
            weight[inside & ~fg] = 0.0
        obj_l = obj_l + (F.binary_cross_entropy_with_logits(o[:, 4], obj_target, reduction="none") * weight).sum()
    n = max(n_fg, 1)
    loss = (IOU_WEIGHT * iou_l + obj_l + cls_l) / n
    return loss, {"iou": float(iou_l.detach()) / n, "obj": float(obj_l.detach()) / n,
                  "cls": float(cls_l.detach()) / n, "fg": n_fg}
