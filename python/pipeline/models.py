"""The networks of ``pipeline`` in PyTorch: the paper's U-Net and the shallow ablation model,
with the ``state_dict`` names ``pipeline export`` writes, so a model trained by ``pipeline
train`` can be fine-tuned or deployed in PyTorch and one trained here read back by
``pipeline deblur --model``. Needs torch.

    from pipeline.models import load
    net = load("unet16.safetensors").eval()          # written by `pipeline export MODEL -o ...`
    y = net(x)                                       # x: (n, 3, h, w) encoded sRGB in [0, 1]

Any frame size works (edges repeated to a multiple of 16 and cropped back, as ``pipeline
deblur`` does). The output is the input plus the predicted residual, not clamped.

A burst U-Net (``pipeline train`` with ``model.type = "burst_unet"``) also takes the time:
``net(x, t)`` with ``t`` in [0, 1] (a float or one per sample) is the sharp image at that
fraction of the exposure; ``net(x)`` is the middle.
"""

import math

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
    """Upsample, concatenate the skip, double convolution; ``film`` (a burst U-Net's timed level
    below the last) conditions the concatenation on the time."""

    def __init__(self, cin, skip, cout, film=False):
        super().__init__()
        self.up = nn.ConvTranspose2d(cin, cin, 2, stride=2)
        self.conv = DoubleConv(cin + skip, cout)
        if film:
            self.film = Film(cin + skip)

    def forward(self, x, s, t=None):
        c = torch.cat([s, self.up(x)], 1)
        return self.conv(self.film(c, t) if hasattr(self, "film") else c)


def time_features(t):
    """The features of times ``t`` (a tensor in [0, 1]) the burst U-Net is conditioned on: with
    s = 2t - 1, s and sin, cos of (j pi s) for j = 1 to 4 (9 per time), as ``pipeline``'s."""
    s = 2 * t - 1
    f = [s]
    for j in range(1, 5):
        f += [torch.sin(math.pi * j * s), torch.cos(math.pi * j * s)]
    return torch.stack(f, -1)


class Film(nn.Module):
    """Time conditioning: ``x * (1 + f(t) @ weight) + f(t) @ bias`` per channel; both start at zero."""

    def __init__(self, c):
        super().__init__()
        self.weight = nn.Parameter(torch.zeros(9, c))
        self.bias = nn.Parameter(torch.zeros(9, c))

    def forward(self, x, t):
        f = time_features(t)
        n, c = x.shape[:2]
        return x * (1 + f @ self.weight).view(n, c, 1, 1) + (f @ self.bias).view(n, c, 1, 1)


class UNet(nn.Module):
    """The paper's U-Net: ``b`` filters at full resolution (64 in the paper), four poolings;
    ``burst=True``: told the time (``Film``) on its last ``levels`` decoder levels (1 to 4), the
    burst U-Net. The last level's conditioning is ``film``, the others' ``ups.K.film``."""

    def __init__(self, b, burst=False, levels=1):
        super().__init__()
        timed = [burst and k + levels >= 4 for k in range(4)]
        self.inc = DoubleConv(3, b)
        self.downs = nn.ModuleList([DoubleConv(i, o) for i, o in [(b, 2 * b), (2 * b, 4 * b), (4 * b, 8 * b), (8 * b, 8 * b)]])
        ups = [(8 * b, 8 * b, 4 * b), (4 * b, 4 * b, 2 * b), (2 * b, 2 * b, b)]
        self.ups = nn.ModuleList([Up(*a, film=f) for a, f in zip(ups, timed)] + [Up(b, b, b)])
        self.outc = nn.Conv2d(b, 3, 1)
        if burst:
            self.film = Film(2 * b)

    def forward(self, x, t=0.5):
        # Any frame size: edges repeated up to a multiple of 16 (four poolings) and cropped back,
        # as `pipeline deblur` does.
        h, w = x.shape[-2:]
        ph, pw = -h % 16, -w % 16
        xp = nn.functional.pad(x, (0, pw, 0, ph), mode="replicate") if ph or pw else x
        xs = [self.inc(xp)]
        for d in self.downs:
            xs.append(d(nn.functional.max_pool2d(xs[-1], 2)))
        y = xs.pop()
        t = torch.as_tensor(t, dtype=x.dtype, device=x.device).expand(x.shape[0])
        for i, u in enumerate(self.ups):
            s = xs.pop()
            if i == len(self.ups) - 1 and hasattr(self, "film"):
                y = u.conv(self.film(torch.cat([s, u.up(y)], 1), t))
            else:
                y = u(y, s, t)
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
    if arch.get("type") == "burst_unet":
        return UNet(int(arch["base"]), burst=True, levels=int(arch.get("levels", 1)))
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
        kind = "burst_unet" if "film.weight" in tensors else "unet"
        arch = {"type": kind, "base": tensors["inc.a.0.weight"].shape[0]}
        if kind == "burst_unet":
            arch["levels"] = 1 + sum(f"ups.{k}.film.weight" in tensors for k in range(3))
    elif "blocks.0.0.weight" in tensors:
        arch = {"type": "shallow", "width": tensors["blocks.0.0.weight"].shape[0]}
    else:
        raise ValueError(f"{path}: neither a U-Net nor a shallow model of pipeline (no inc.a.0.weight or blocks.0.0.weight)")
    net = build(arch)
    net.load_state_dict({k: torch.from_numpy(v) for k, v in tensors.items()})
    return net
