"""PyTorch CPU baseline for `pipeline bench train`: the same U-Net and shallow model as
src/model/mod.rs, timed the same way (training step with Huber loss and Adam on a batch of
128x128 patches; forward of one patch in eval mode). Prints one JSON object.

Usage: python3 benches/torch_models.py unet|shallow WIDTH BATCH REPEATS
       python3 benches/torch_models.py infer unet|shallow WIDTH HEIGHT FRAME_WIDTH REPEATS
Skipped by `pipeline bench train` when torch is not installed.
"""
import json, os, statistics, sys, time

import torch
from torch import nn

# The same thread count as the Rust side (`pipeline bench` passes its rayon pool size).
if os.environ.get("TORCH_THREADS"):
    torch.set_num_threads(int(os.environ["TORCH_THREADS"]))


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
    def __init__(self, b):
        super().__init__()
        self.inc = DoubleConv(3, b)
        self.downs = nn.ModuleList([DoubleConv(i, o) for i, o in [(b, 2 * b), (2 * b, 4 * b), (4 * b, 8 * b), (8 * b, 8 * b)]])
        self.ups = nn.ModuleList([Up(8 * b, 8 * b, 4 * b), Up(4 * b, 4 * b, 2 * b), Up(2 * b, 2 * b, b), Up(b, b, b)])
        self.outc = nn.Conv2d(b, 3, 1)

    def forward(self, x):
        xs = [self.inc(x)]
        for d in self.downs:
            xs.append(d(nn.functional.max_pool2d(xs[-1], 2)))
        y = xs.pop()
        for u in self.ups:
            y = u(y, xs.pop())
        return x + self.outc(y)


class Shallow(nn.Module):
    def __init__(self, w):
        super().__init__()
        self.blocks = nn.ModuleList([conv_bn(3 if i == 0 else w, w) for i in range(9)])
        self.out = nn.Conv2d(w, 3, 3, padding=1)

    def forward(self, x):
        y = x
        for b in self.blocks:
            y = torch.relu(b(y))
        return x + self.out(y)


def infer(kind, width, h, w, repeats):
    """Whole-frame forward (eval mode, no grad) of an h x w frame: frames/s, median of repeats."""
    torch.manual_seed(7)
    model = (UNet(width) if kind == "unet" else Shallow(width)).eval()
    # The U-Net needs sides divisible by 16, as src/model pads them.
    ph, pw = -(-h // 16) * 16, -(-w // 16) * 16
    x = torch.rand(1, 3, ph if kind == "unet" else h, pw if kind == "unet" else w)
    times = []
    with torch.no_grad():
        for r in range(repeats + 1):
            t = time.perf_counter()
            model(x)
            if r:
                times.append(time.perf_counter() - t)
    print(json.dumps({"threads": torch.get_num_threads(), "frames_per_s_median": 1.0 / statistics.median(times)}))


def main():
    if sys.argv[1] == "infer":
        infer(sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5]), int(sys.argv[6]))
        return
    kind, width, batch, repeats = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
    torch.manual_seed(7)
    model = UNet(width) if kind == "unet" else Shallow(width)
    opt = torch.optim.Adam(model.parameters(), lr=1e-4)
    loss_fn = nn.HuberLoss(delta=0.02)
    x, y = torch.rand(batch, 3, 128, 128), torch.rand(batch, 3, 128, 128)
    steps = []
    for r in range(repeats + 1):
        t = time.perf_counter()
        opt.zero_grad()
        loss_fn(model(x), y).backward()
        opt.step()
        if r:
            steps.append(time.perf_counter() - t)
    model.eval()
    fwd = []
    with torch.no_grad():
        for r in range(repeats + 1):
            t = time.perf_counter()
            model(x[:1])
            if r:
                fwd.append((time.perf_counter() - t) * 1e3)
    print(json.dumps({"threads": torch.get_num_threads(), "train_patches_per_s_median": batch / statistics.median(steps), "forward_ms_per_patch_median": statistics.median(fwd)}))


if __name__ == "__main__":
    main()
