"""YOLOX-Nano as a trainable PyTorch model, loaded from the bundled ONNX export (needs torch).

Architecture (Ge et al. 2021, "YOLOX: Exceeding YOLO Series in 2021"), Nano scale: depth
0.33, width 0.25, depthwise separable 3x3 convolutions, SiLU. Backbone: a space-to-depth stem,
four CSP stages (the last with spatial pyramid pooling, 5/9/13); neck: a PAFPN over strides
8, 16, 32; head: per level a 1x1 stem and decoupled class and box/objectness branches. The
ONNX file holds 113 convolutions with BatchNorm folded into their weights and biases; they map
one to one, in execution order, onto this model's convolutions (`load_onnx`).

Folded BatchNorm cannot simply be left out for fine-tuning: with no normalisation the
activations' scale is whatever the folded weights give, and the loss diverges within a few
steps; with a fresh BatchNorm (mean 0, variance 1) the train-mode batch statistics change
every layer's output. `unfold_batchnorm` measures each convolution's output statistics on
real images and puts them into the BatchNorm (running mean/var, and gamma/beta chosen so
that the network computes exactly what the ONNX model computes), so train mode starts from
the pretrained function.

Output layout as the ONNX export (and blendgen.detection.detector): per anchor point
(cx, cy, log w, log h) raw, objectness and 80 class scores through a sigmoid.
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import nn

from blendgen.errors import UserError

DEPTH, WIDTH = 0.33, 0.25
STRIDES = (8, 16, 32)
NUM_CLASSES = 80
BN_EPS, BN_MOMENTUM = 1e-3, 0.03


class ConvBnAct(nn.Module):
    """Conv2d (no bias) -> BatchNorm -> SiLU."""

    def __init__(self, c_in: int, c_out: int, k: int, stride: int = 1, groups: int = 1):
        super().__init__()
        self.conv = nn.Conv2d(c_in, c_out, k, stride, (k - 1) // 2, groups=groups, bias=False)
        self.bn = nn.BatchNorm2d(c_out, eps=BN_EPS, momentum=BN_MOMENTUM)
        self.act = nn.SiLU(inplace=True)

    def forward(self, x):
        return self.act(self.bn(self.conv(x)))


class SeparableConv(nn.Module):
    """Depthwise k x k (with stride) then pointwise 1x1, each with BatchNorm and SiLU."""

    def __init__(self, c_in: int, c_out: int, k: int = 3, stride: int = 1):
        super().__init__()
        self.depthwise = ConvBnAct(c_in, c_in, k, stride, groups=c_in)
        self.pointwise = ConvBnAct(c_in, c_out, 1)

    def forward(self, x):
        return self.pointwise(self.depthwise(x))


class Bottleneck(nn.Module):
    def __init__(self, c: int, residual: bool):
        super().__init__()
        self.reduce = ConvBnAct(c, c, 1)
        self.spatial = SeparableConv(c, c, 3)
        self.residual = residual

    def forward(self, x):
        y = self.spatial(self.reduce(x))
        return x + y if self.residual else y


class CSPBlock(nn.Module):
    """Cross-stage partial block: half the channels through n bottlenecks, half around them."""

    def __init__(self, c_in: int, c_out: int, n: int, residual: bool = True):
        super().__init__()
        hidden = c_out // 2
        self.main = ConvBnAct(c_in, hidden, 1)
        self.bypass = ConvBnAct(c_in, hidden, 1)
        self.blocks = nn.Sequential(*[Bottleneck(hidden, residual) for _ in range(n)])
        self.merge = ConvBnAct(2 * hidden, c_out, 1)

    def forward(self, x):
        a = self.main(x)
        b = self.bypass(x)
        return self.merge(torch.cat([self.blocks(a), b], dim=1))


class SpatialPyramidPool(nn.Module):
    def __init__(self, c_in: int, c_out: int, sizes=(5, 9, 13)):
        super().__init__()
        hidden = c_in // 2
        self.reduce = ConvBnAct(c_in, hidden, 1)
        self.pools = nn.ModuleList(nn.MaxPool2d(k, 1, k // 2) for k in sizes)
        self.merge = ConvBnAct(hidden * (len(sizes) + 1), c_out, 1)

    def forward(self, x):
        x = self.reduce(x)
        return self.merge(torch.cat([x] + [p(x) for p in self.pools], dim=1))


class SpaceToDepthStem(nn.Module):
    """Every 2x2 pixel block becomes 4 channels (order: even/even, odd-row, odd-column, odd/odd),
    then a 3x3 convolution."""

    def __init__(self, c_out: int):
        super().__init__()
        self.conv = ConvBnAct(12, c_out, 3)

    def forward(self, x):
        return self.conv(torch.cat([x[..., ::2, ::2], x[..., 1::2, ::2], x[..., ::2, 1::2], x[..., 1::2, 1::2]], 1))


def _depth(n: int) -> int:
    return max(round(n * DEPTH), 1)


class Backbone(nn.Module):
    def __init__(self):
        super().__init__()
        c = int(64 * WIDTH)  # 16
        self.stem = SpaceToDepthStem(c)
        self.stage2 = nn.Sequential(SeparableConv(c, 2 * c, 3, 2), CSPBlock(2 * c, 2 * c, _depth(3)))
        self.stage3 = nn.Sequential(SeparableConv(2 * c, 4 * c, 3, 2), CSPBlock(4 * c, 4 * c, _depth(9)))
        self.stage4 = nn.Sequential(SeparableConv(4 * c, 8 * c, 3, 2), CSPBlock(8 * c, 8 * c, _depth(9)))
        self.stage5 = nn.Sequential(SeparableConv(8 * c, 16 * c, 3, 2), SpatialPyramidPool(16 * c, 16 * c),
                                    CSPBlock(16 * c, 16 * c, _depth(3), residual=False))

    def forward(self, x):
        c3 = self.stage3(self.stage2(self.stem(x)))
        c4 = self.stage4(c3)
        return c3, c4, self.stage5(c4)


class PAFPN(nn.Module):
    """Top-down then bottom-up path aggregation over strides 8, 16, 32."""

    def __init__(self):
        super().__init__()
        c3, c4, c5 = int(256 * WIDTH), int(512 * WIDTH), int(1024 * WIDTH)  # 64, 128, 256
        n = _depth(3)
        self.lateral5 = ConvBnAct(c5, c4, 1)
        self.top_down4 = CSPBlock(2 * c4, c4, n, residual=False)
        self.lateral4 = ConvBnAct(c4, c3, 1)
        self.top_down3 = CSPBlock(2 * c3, c3, n, residual=False)
        self.down3 = SeparableConv(c3, c3, 3, 2)
        self.bottom_up4 = CSPBlock(2 * c3, c4, n, residual=False)
        self.down4 = SeparableConv(c4, c4, 3, 2)
        self.bottom_up5 = CSPBlock(2 * c4, c5, n, residual=False)
        self.up = nn.Upsample(scale_factor=2, mode="nearest")

    def forward(self, feats):
        c3, c4, c5 = feats
        p5 = self.lateral5(c5)
        t4 = self.top_down4(torch.cat([self.up(p5), c4], 1))
        p4 = self.lateral4(t4)
        out3 = self.top_down3(torch.cat([self.up(p4), c3], 1))
        out4 = self.bottom_up4(torch.cat([self.down3(out3), p4], 1))
        out5 = self.bottom_up5(torch.cat([self.down4(out4), p5], 1))
        return out3, out4, out5


class HeadLevel(nn.Module):
    def __init__(self, c_in: int, c: int, num_classes: int):
        super().__init__()
        self.stem = ConvBnAct(c_in, c, 1)
        self.cls_branch = nn.Sequential(SeparableConv(c, c, 3), SeparableConv(c, c, 3))
        self.cls_pred = nn.Conv2d(c, num_classes, 1)
        self.reg_branch = nn.Sequential(SeparableConv(c, c, 3), SeparableConv(c, c, 3))
        self.reg_pred = nn.Conv2d(c, 4, 1)
        self.obj_pred = nn.Conv2d(c, 1, 1)

    def forward(self, x):
        x = self.stem(x)
        cls = self.cls_pred(self.cls_branch(x))
        reg_feat = self.reg_branch(x)
        return torch.cat([self.reg_pred(reg_feat), self.obj_pred(reg_feat), cls], 1)  # logits


class YoloxNano(nn.Module):
    def __init__(self, num_classes: int = NUM_CLASSES):
        super().__init__()
        self.backbone = Backbone()
        self.neck = PAFPN()
        c = int(256 * WIDTH)
        self.head = nn.ModuleList(HeadLevel(int(ch * WIDTH), c, num_classes) for ch in (256, 512, 1024))
        self._grid_cache: dict = {}

    def forward(self, x):
        """(B, N, 5 + classes): box regression raw, objectness and class *logits* per anchor point
        (strides 8, 16, 32, row-major per level)."""
        feats = self.neck(self.backbone(x))
        return torch.cat([h(f).flatten(2) for h, f in zip(self.head, feats)], 2).permute(0, 2, 1)

    def grids(self, h: int, w: int, device=None) -> tuple[torch.Tensor, torch.Tensor]:
        """Anchor-point grid (N, 2) and stride (N, 1) for an h x w input."""
        key = (h, w, device)
        if key not in self._grid_cache:
            g, s = [], []
            for st in STRIDES:
                yv, xv = torch.meshgrid(torch.arange(h // st), torch.arange(w // st), indexing="ij")
                g.append(torch.stack([xv, yv], 2).reshape(-1, 2))
                s.append(torch.full((g[-1].shape[0], 1), float(st)))
            self._grid_cache[key] = (torch.cat(g).float().to(device), torch.cat(s).to(device))
        return self._grid_cache[key]

    def predict(self, x):
        """As the ONNX model: regression raw, objectness and class scores through a sigmoid."""
        out = self.forward(x)
        return torch.cat([out[..., :4], out[..., 4:].sigmoid()], -1)


def conv_layers(model: nn.Module) -> list[nn.Conv2d]:
    """The model's convolutions in execution order (a forward pass on a small input, recorded)."""
    order: list[nn.Conv2d] = []
    hooks = [m.register_forward_hook(lambda mod, i, o: order.append(mod)) for m in model.modules()
             if isinstance(m, nn.Conv2d)]
    was = model.training
    model.eval()
    with torch.no_grad():
        model(torch.zeros(1, 3, 64, 64))
    model.train(was)
    for h in hooks:
        h.remove()
    return order


def load_onnx(path: Path) -> YoloxNano:
    """YOLOX-Nano with the ONNX model's weights (BatchNorm folded: identity BatchNorms whose
    beta holds the folded bias); `unfold_batchnorm` before training."""
    from blendgen.train.onnx_weights import read_convs

    nodes = read_convs(Path(path))
    model = YoloxNano()
    convs = conv_layers(model)
    if len(nodes) != len(convs):
        raise UserError(f"has {len(nodes)} convolutions, YOLOX-Nano has {len(convs)}: not a YOLOX-Nano export",
                        where=str(path))
    bns = {m.conv: m.bn for m in model.modules() if isinstance(m, ConvBnAct)}
    with torch.no_grad():
        for k, (node, conv) in enumerate(zip(nodes, convs)):
            if tuple(node.weight.shape) != tuple(conv.weight.shape) or node.attrs.get("group", 1) != conv.groups \
                    or list(node.attrs.get("strides", [1, 1])) != list(conv.stride):
                raise UserError(f"convolution {k} ({node.name}) is {node.weight.shape} (group "
                                f"{node.attrs.get('group', 1)}, stride {node.attrs.get('strides')}), YOLOX-Nano's is "
                                f"{tuple(conv.weight.shape)} (group {conv.groups}, stride {conv.stride}): not a "
                                "YOLOX-Nano export", where=str(path))
            conv.weight.copy_(torch.from_numpy(node.weight))
            bias = torch.from_numpy(node.bias) if node.bias is not None else torch.zeros(conv.out_channels)
            if conv in bns:
                bn = bns[conv]
                bn.running_mean.zero_()
                bn.running_var.fill_(1.0 - bn.eps)
                bn.weight.fill_(1.0)
                bn.bias.copy_(bias)
            else:
                conv.bias.copy_(bias)
    return model


def unfold_batchnorm(model: YoloxNano, images: torch.Tensor, batch: int = 8) -> None:
    """Set every BatchNorm to the statistics of its convolution's output on `images` (N, 3, H, W,
    preprocessed as for training) without changing what the model computes in eval mode:
    running mean m and variance v measured, gamma = sqrt(v + eps), beta = folded bias + m."""
    stats: dict = {}

    def hook(mod, inp, out):
        o = out.detach().double()
        s = stats.setdefault(mod, [0.0, 0.0, 0])
        s[0] = s[0] + o.sum(dim=(0, 2, 3))
        s[1] = s[1] + (o * o).sum(dim=(0, 2, 3))
        s[2] += o.numel() // o.shape[1]

    blocks = [m for m in model.modules() if isinstance(m, ConvBnAct)]
    hooks = [b.conv.register_forward_hook(hook) for b in blocks]
    model.eval()
    with torch.no_grad():
        for i in range(0, len(images), batch):
            model(images[i:i + batch])
    for h in hooks:
        h.remove()
    with torch.no_grad():
        for b in blocks:
            s1, s2, n = stats[b.conv]
            mean = s1 / n
            var = (s2 / n - mean * mean).clamp_min(1e-8)
            # current function: y = (conv - rm) / sqrt(rv + eps) * g + beta, with the loaded identity BN
            scale = b.bn.weight.double() / torch.sqrt(b.bn.running_var.double() + b.bn.eps)
            shift = b.bn.bias.double() - b.bn.running_mean.double() * scale
            std = torch.sqrt(var + b.bn.eps)
            b.bn.running_mean.copy_(mean.float())
            b.bn.running_var.copy_(var.float())
            b.bn.weight.copy_((scale * std).float())
            b.bn.bias.copy_((shift + mean * scale).float())
