"""PyTorch CPU baseline for `pipeline bench train`: the same U-Net and shallow model as
src/model/mod.rs, timed the same way (training step with Huber loss and Adam on a batch of
128x128 patches; forward of one patch in eval mode). Prints one JSON object.

Usage: python3 benches/torch_models.py unet|shallow WIDTH BATCH REPEATS
       python3 benches/torch_models.py infer unet|shallow WIDTH HEIGHT FRAME_WIDTH REPEATS
       python3 benches/torch_models.py burst WIDTH HEIGHT FRAME_WIDTH K REPEATS
Skipped by `pipeline bench train` when torch is not installed.
"""
import importlib.util, json, os, statistics, sys, time

import torch
from torch import nn

# The same thread count as the Rust side (`pipeline bench` passes its rayon pool size).
if os.environ.get("TORCH_THREADS"):
    torch.set_num_threads(int(os.environ["TORCH_THREADS"]))


# The networks are the Python package's (python/pipeline/models.py), loaded by path so this
# script runs without building the package.
_spec = importlib.util.spec_from_file_location("pipeline_models", os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "python", "pipeline", "models.py"))
_models = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_models)
UNet, Shallow = _models.UNet, _models.Shallow


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


def burst(width, h, w, k, repeats):
    """K frames of a burst U-Net from one h x w capture, one forward per time as the network is
    written (model(x, t)): seconds for the K frames, median of repeats."""
    torch.manual_seed(7)
    model = UNet(width, burst=True).eval()
    x = torch.rand(1, 3, -(-h // 16) * 16, -(-w // 16) * 16)
    times = []
    with torch.no_grad():
        for r in range(repeats + 1):
            t = time.perf_counter()
            for i in range(k):
                model(x, (i + 0.5) / k)
            if r:
                times.append(time.perf_counter() - t)
    print(json.dumps({"threads": torch.get_num_threads(), "k": k, "seconds_median": statistics.median(times)}))


def main():
    if sys.argv[1] == "burst":
        burst(*(int(a) for a in sys.argv[2:7]))
        return
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
        # One patch is short (10-100 ms): ten times the repeats, as src/commands/bench/train.rs.
        for r in range(10 * repeats + 1):
            t = time.perf_counter()
            model(x[:1])
            if r:
                fwd.append((time.perf_counter() - t) * 1e3)
    print(json.dumps({"threads": torch.get_num_threads(), "train_patches_per_s_median": batch / statistics.median(steps), "forward_ms_per_patch_median": statistics.median(fwd)}))


if __name__ == "__main__":
    main()
