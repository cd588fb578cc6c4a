"""The networks of ``pipeline`` in PyTorch: the paper's U-Net and the shallow ablation model,
with the ``state_dict`` names ``pipeline export`` writes, so a model trained by ``pipeline
train`` can be fine-tuned or deployed in PyTorch and one trained here read back by
``pipeline deblur --model``. Needs torch.

    from pipeline.models import load
    net = load("unet16.safetensors").eval()          # written by `pipeline export MODEL -o ...`
    y = net(x)                                       # x: (n, 3, h, w) encoded sRGB in [0, 1]

The U-Net needs sides divisible by 16 (pad first, as ``pipeline deblur`` does). The output is
the input plus the predicted residual, not clamped.
"""

import json

import torch
from torch import nn


def conv_bn(cin, cout):
    return nn.Sequential(nn.Conv2d(cin, cout, 3, padding=1, bias=False), nn.BatchNorm2d(cout))


class DoubleConv(nn.Module):
    def __init__(self, cin, cout):
        super().__init__()
        self.a, self.b = conv_bn(cin, cout), conv_bn(cout, cout)

    def forward(self, x):
        x = nn.functional.leaky_relu(self.a(x), 0.01)
        return nn.functional.leaky_relu(self.b(x), 0.01)


class Up(nn.Module):
    def __init__(self, cin, skip, cout):
        super().__init__()
        self.up = nn.ConvTranspose2d(cin, cin, 2, stride=2)
        self.conv = DoubleConv(cin + skip, cout)

    def forward(self, x, s):
        return self.conv(torch.cat([s, self.up(x)], 1))


class UNet(nn.Module):
    """The paper's U-Net: ``b`` filters at full resolution (64 in the paper), four poolings."""

    def __init__(self, b):
        super().__init__()
        self.inc = DoubleConv(3, b)
        self.downs = nn.ModuleList([DoubleConv(i, o) for i, o in [(b, 2 * b), (2 * b, 4 * b), (4 * b, 8 * b), (8 * b, 8 * b)]])
        self.ups = nn.ModuleList([Up(8 * b, 8 * b, 4 * b), Up(4 * b, 4 * b, 2 * b), Up(2 * b, 2 * b, b), Up(b, b, b)])
        self.outc = nn.Conv2d(b, 3, 1)

    def forward(self, x):
        # Any frame size: edges repeated up to a multiple of 16 (four poolings) and cropped back,
        # as `pipeline deblur` does.
        h, w = x.shape[-2:]
        ph, pw = -h % 16, -w % 16
        xp = nn.functional.pad(x, (0, pw, 0, ph), mode="replicate") if ph or pw else x
        xs = [self.inc(xp)]
        for d in self.downs:
            xs.append(d(nn.functional.max_pool2d(xs[-1], 2)))
        y = xs.pop()
        for u in self.ups:
            y = u(y, xs.pop())
        return (xp + self.outc(y))[..., :h, :w]


class Shallow(nn.Module):
    """The shallow ablation model: nine 3x3 convolution + BatchNorm + ReLU blocks of ``w`` filters."""

    def __init__(self, w):
        super().__init__()
        self.blocks = nn.ModuleList([conv_bn(3 if i == 0 else w, w) for i in range(9)])
        self.out = nn.Conv2d(w, 3, 3, padding=1)

    def forward(self, x):
        y = x
        for b in self.blocks:
            y = torch.relu(b(y))
        return x + self.out(y)


def build(arch):
    """A fresh network of ``arch``: ``{"type": "unet", "base": 16}`` or ``{"type": "shallow", "width": 32}``."""
    if arch.get("type") == "unet":
        return UNet(int(arch["base"]))
    if arch.get("type") == "shallow":
        return Shallow(int(arch["width"]))
    raise ValueError(f"unknown architecture {arch!r}")


def load(path):
    """The network in a safetensors file with PyTorch names (``pipeline export``), its weights loaded."""
    from .safetensors import load_safetensors

    tensors, meta = load_safetensors(path)
    if any(k.startswith(("Unet.", "Shallow.")) for k in tensors):
        raise ValueError(f"{path}: has burn's parameter names; write PyTorch names with `pipeline export {path} -o OUT.safetensors`")
    if "arch" in meta:
        arch = json.loads(meta["arch"])
    elif "inc.a.0.weight" in tensors:
        arch = {"type": "unet", "base": tensors["inc.a.0.weight"].shape[0]}
    elif "blocks.0.0.weight" in tensors:
        arch = {"type": "shallow", "width": tensors["blocks.0.0.weight"].shape[0]}
    else:
        raise ValueError(f"{path}: neither a U-Net nor a shallow model of pipeline (no inc.a.0.weight or blocks.0.0.weight)")
    net = build(arch)
    net.load_state_dict({k: torch.from_numpy(v) for k, v in tensors.items()})
    return net
