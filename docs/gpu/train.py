"""Trains the U-Net pair (and the shallow model) in PyTorch on a GPU, on shards that `pipeline run
pipelines/train-data.toml` keeps writing while it trains (docs/gpu/run.sh starts both).

The networks are `python/pipeline/models.py`'s, whose parameter names `pipeline deblur --model` and
`pipeline eval` read back. Every model sees the same samples in the same order (one index draw per
step serves them all); the coded and the conventional shards are rendered from the same seeds, so
they hold the same sharp patches, motions and noise, and differ only in the camera.

    python3 docs/gpu/train.py --coded DIR --conventional DIR --out OUT --until UNIX_TIME [--nets unet32:coded,...]

Burst shards (`transforms.blur.burst = true`: key.gt.00.png ... one target per sub-frame) train
burst U-Nets (`--nets burst-unet32:coded,burst-unet32:conventional`; `burst-unet32f4` tells the time
to all four decoder levels): each step draws one sub-frame k per sample, the time t = (k + 0.5) / K
and that sub-frame as the target, as `pipeline train` does. A single-frame net on burst shards
learns the middle sub-frame.

What it does, as models/README.md describes for the CPU trainer: Huber loss (delta 0.02) on
encoded values in [0, 1], Adam (eps 1e-8), flips and 90-degree rotations, the last layer zeroed
(each net starts as the identity), a warm-up then a cosine decay that ends at --until; weights
kept as an exponential moving average, whose BatchNorm statistics are recomputed at the end over
50 batches (exact averages, as `validate.bn_batches`). A shard whose name hashes to 0 mod 20 is
held out for validation (PSNR of input and output, 8-bit). Each model is written as
OUT/NAME.safetensors (PyTorch names, `arch` in the metadata) every --save-every seconds and at the
end; OUT/history.csv has the losses; OUT/train.log what happened.
"""

import argparse
import csv
import glob
import importlib.util
import io
import json
import math
import os
import tarfile
import threading
import time
import zlib

import numpy as np
import torch
from PIL import Image

HERE = os.path.dirname(os.path.abspath(__file__))
spec = importlib.util.spec_from_file_location("pipeline_models", os.path.join(HERE, "..", "..", "python", "pipeline", "models.py"))
models = importlib.util.module_from_spec(spec)
spec.loader.exec_module(models)


def log(msg, f=None):
    line = f"[{time.strftime('%H:%M:%S')}] {msg}"
    print(line, flush=True)
    if f:
        f.write(line + "\n")
        f.flush()


def read_shard(path):
    """{key: (lq uint8 HWC, [gt uint8 HWC, ...])} of one WebDataset shard: key.lq.png with key.gt.png
    (one target) or key.gt.00.png, key.gt.01.png, ... (a burst: one per sub-frame, in time order)."""
    out = {}
    with tarfile.open(path) as t:
        for m in t.getmembers():
            key, _, ext = m.name.partition(".")
            if not (ext == "lq.png" or (ext.startswith("gt.") and ext.endswith(".png"))):
                continue
            img = np.asarray(Image.open(io.BytesIO(t.extractfile(m).read())).convert("RGB"))
            out.setdefault(key, {})[ext[:-4]] = img
    samples = {}
    for k, v in out.items():
        gts = [v[g] for g in sorted(g for g in v if g.startswith("gt"))]
        if "lq" in v and gts:
            samples[k] = (v["lq"], gts)
    return samples


class Pool:
    """Samples of both cameras, loaded by a thread as their shards appear (a shard counts once it
    exists under the same name in both folders). Train and validation stay apart by shard name."""

    def __init__(self, dirs, logf):
        self.dirs, self.logf = dirs, logf
        self.seen = set()
        self.lock = threading.Lock()
        self.new = {"train": [], "val": []}
        self.mismatch = 0
        self.stop = False
        threading.Thread(target=self.run, daemon=True).start()

    def run(self):
        while not self.stop:
            names = [{os.path.relpath(p, d) for p in glob.glob(f"{d}/**/*.tar", recursive=True)} for d in self.dirs]
            both = sorted(set.intersection(*names) - self.seen)
            for n in both:
                try:
                    shards = [read_shard(os.path.join(d, n)) for d in self.dirs]
                except Exception as e:  # a shard being replaced: try again next round
                    log(f"{n}: {e}", self.logf)
                    continue
                self.seen.add(n)
                keys = sorted(set.intersection(*[set(s) for s in shards]))
                rows = []
                for k in keys:
                    gts = [np.stack(s[k][1]) for s in shards]
                    if any(g.shape != gts[0].shape or not np.array_equal(gts[0], g) for g in gts[1:]):
                        self.mismatch += 1  # the cameras must share the sharp patches
                        continue
                    rows.append(np.stack([s[k][0] for s in shards] + list(gts[0])))
                if rows:
                    split = "val" if zlib.crc32(os.path.basename(n).encode()) % 20 == 0 else "train"
                    with self.lock:
                        self.new[split].append(np.stack(rows))
            time.sleep(1.0)

    def take(self, split):
        with self.lock:
            got, self.new[split] = self.new[split], []
        return got


def torch_name(burn):
    """pipeline's parameter name -> python/pipeline/models.py's (the rules of src/model/torch.rs's
    torch_name): `Unet.down1.conv.a.conv.weight` -> `downs.0.a.0.weight`, `bn.gamma` -> `1.weight`."""
    net, _, rest = burn.partition(".")
    parts, out, i = rest.split("."), [], 0
    while i < len(parts):
        p, nxt = parts[i], parts[i + 1] if i + 1 < len(parts) else None
        if net == "Unet" and p.startswith("down"):
            out.append(f"downs.{int(p[4:]) - 1}")
            i += nxt == "conv"
        elif net == "Unet" and p.startswith("up") and p[2:].isdigit():
            out.append(f"ups.{int(p[2:]) - 1}")
        elif p == "conv" and nxt in ("weight", "bias"):
            out.append("0")
        else:
            out.append({"bn": "1", "gamma": "weight", "beta": "bias"}.get(p, p))
        i += 1
    return ".".join(out)


def load_init(net, path):
    """Weights from a safetensors file with PyTorch names or with pipeline's own (a shipped
    models/NAME/model.safetensors), F32 or F16."""
    from safetensors.torch import load_file

    sd = load_file(path)
    if any(k.startswith(("Unet.", "Shallow.")) for k in sd):
        sd = {torch_name(k): v for k, v in sd.items()}
    missing, unexpected = net.load_state_dict(sd, strict=False)
    # A burst U-Net told the time on more levels than the file's starts their conditioning at
    # zero (the file's network at every time), as `pipeline train` does with `init`.
    if unexpected or any(not k.endswith("num_batches_tracked") and ".film." not in k for k in missing):
        raise SystemExit(f"{path}: does not fit {type(net).__name__} (missing {missing}, unexpected {unexpected})")


class Samples:
    """The samples on the device, [n, (coded, conventional, gt...), c, h, w] uint8 (one gt, or K
    for a burst), in one buffer that doubles when full (a torch.cat per new shard would copy every
    earlier sample again). The first shard sets the layout; a shard of another is left out."""

    def __init__(self, dev, logf=None):
        self.buf = None
        self.dev, self.logf = dev, logf
        self.n = 0

    @property
    def targets(self):
        """Targets per sample: 1, or K for burst shards (0 before the first shard)."""
        return 0 if self.buf is None else self.buf.shape[1] - 2

    def add(self, chunks):
        for c in chunks:
            t = torch.from_numpy(c).permute(0, 1, 4, 2, 3)
            if self.buf is None:
                self.buf = torch.empty((0, *t.shape[1:]), dtype=torch.uint8, device=self.dev)
            if t.shape[1:] != self.buf.shape[1:]:
                log(f"a shard of samples {tuple(t.shape[1:])} among {tuple(self.buf.shape[1:])}: left out", self.logf)
                continue
            if self.n + len(t) > len(self.buf):
                grown = self.buf.new_empty((max(2 * len(self.buf), self.n + len(t), 1024), *self.buf.shape[1:]))
                grown[:self.n] = self.buf[:self.n]
                self.buf = grown
            self.buf[self.n:self.n + len(t)] = t.to(self.buf.device)
            self.n += len(t)

    def __len__(self):
        return self.n

    def times(self, k):
        """The times of sub-frames `k` (a tensor) as fractions of the exposure."""
        return (k.float() + 0.5) / self.targets

    def __getitem__(self, i):
        return self.buf[:self.n][i]


def huber(x, y, d=0.02):
    a = (x - y).abs()
    return torch.where(a < d, 0.5 * a * a, d * (a - 0.5 * d)).mean()


def augment(x, g):
    """The same random flip / 90-degree rotation for the whole batch's lq and gt (dims 3, 4)."""
    k = int(torch.randint(0, 8, (1,), generator=g))
    if k & 1:
        x = x.flip(-1)
    if k & 2:
        x = x.flip(-2)
    if k & 4:
        x = x.transpose(-1, -2)
    return x


def psnr(a, b):
    """PSNR in dB of 8-bit images (values in [0, 1], rounded to 8 bits first), per sample."""
    a = (a.clamp(0, 1) * 255).round()
    b = (b.clamp(0, 1) * 255).round()
    mse = ((a - b) ** 2).flatten(1).mean(1).clamp_min(1e-10)
    return 10 * torch.log10(255.0**2 / mse)


def save(net, arch, path, extra):
    from safetensors.torch import save_file

    sd = {k: v.detach().float().contiguous().cpu() if v.is_floating_point() else v.detach().contiguous().cpu() for k, v in net.state_dict().items()}
    tmp = path + ".tmp"
    save_file(sd, tmp, metadata={"format": "pt", "arch": json.dumps(arch), **{k: str(v) for k, v in extra.items()}})
    os.replace(tmp, path)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--coded", required=True)
    ap.add_argument("--conventional", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--until", type=float, required=True, help="unix time at which training ends (the schedule ends there)")
    ap.add_argument("--nets", default="unet32:coded,unet32:conventional,unet16:coded,shallow32:coded",
                    help="NET:CAMERA,...: unetB (base B) or shallowW (width W), on coded or conventional data")
    ap.add_argument("--max-wait", type=float, default=120.0, help="seconds to wait for the first --min-samples")
    ap.add_argument("--init", default="", help="folder of NAME.safetensors or NAME/model.safetensors (models/ itself) to start each net from")
    ap.add_argument("--batch", type=int, default=64)
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--warmup", type=float, default=20.0, help="seconds of linear warm-up")
    ap.add_argument("--min-samples", type=int, default=2000)
    ap.add_argument("--save-every", type=float, default=60.0)
    ap.add_argument("--ema", type=float, default=0.999)
    ap.add_argument("--burst-ends", type=float, default=0.0,
                    help="burst nets: share of samples learnt at the first or last sub-frame (pipeline train's data.burst_ends)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    logf = open(os.path.join(a.out, "train.log"), "a")
    dev = torch.device(a.device)
    torch.manual_seed(a.seed)
    g = torch.Generator().manual_seed(a.seed)
    torch.backends.cudnn.benchmark = True
    torch.backends.cuda.matmul.allow_tf32 = True
    torch.backends.cudnn.allow_tf32 = True
    amp = dev.type == "cuda"
    log(f"device {dev} ({torch.cuda.get_device_name() if amp else 'cpu'}), torch {torch.__version__}", logf)

    specs = []
    for item in a.nets.split(","):
        kind, cam = item.split(":")
        if kind.startswith("burst-unet"):
            base, _, levels = kind[10:].partition("f")
            arch = {"type": "burst_unet", "base": int(base), **({"levels": int(levels)} if levels else {})}
        elif kind.startswith("unet"):
            arch = {"type": "unet", "base": int(kind[4:])}
        else:
            arch = {"type": "shallow", "width": int(kind[7:])}
        specs.append((f"{kind}-{cam}", arch, {"coded": 0, "conventional": 1}[cam]))
    nets = []
    for name, arch, cam in specs:
        net = models.build(arch)
        last = net.outc if arch["type"] in ("unet", "burst_unet") else net.out
        torch.nn.init.zeros_(last.weight)
        torch.nn.init.zeros_(last.bias)
        for init in [os.path.join(a.init, name + ".safetensors"), os.path.join(a.init, name, "model.safetensors")] if a.init else []:
            if os.path.exists(init):
                load_init(net, init)
                log(f"{name}: started from {init}", logf)
                break
        net = net.to(dev).to(memory_format=torch.channels_last)
        ema = models.build(arch).to(dev).to(memory_format=torch.channels_last)
        ema.load_state_dict(net.state_dict())
        for p in ema.parameters():
            p.requires_grad_(False)
        opt = torch.optim.Adam(net.parameters(), lr=a.lr, eps=1e-8)
        nparams = sum(p.numel() for p in net.parameters())
        log(f"{name}: {nparams} parameters", logf)
        nets.append({"name": name, "arch": arch, "cam": cam, "net": net, "ema": ema, "opt": opt, "loss": 0.0, "n": 0,
                     "ema_p": list(ema.parameters()), "net_p": list(net.parameters()),
                     "ema_b": list(ema.buffers()), "net_b": list(net.buffers())})

    t_start = time.time()
    pool = Pool([a.coded, a.conventional], logf)
    data, val = Samples(dev, logf), Samples(dev, logf)

    def absorb():
        data.add(pool.take("train"))
        val.add(pool.take("val"))

    while True:
        absorb()
        if len(data) >= a.min_samples:
            break
        if time.time() > min(a.until, t_start + a.max_wait):
            raise SystemExit(f"only {len(data)} samples after {time.time() - t_start:.0f} s: is the generator running? (its logs)")
        time.sleep(1)
    t0 = time.time()
    span = max(a.until - t0, 1.0)
    log(f"training from {len(data)} samples ({len(val)} held out); {span:.0f} s until the end of the schedule", logf)
    hist = open(os.path.join(a.out, "history.csv"), "a", newline="")
    hw = csv.writer(hist)
    hw.writerow(["step", "seconds", "samples", "lr"] + [n["name"] for n in nets])
    step, last_save, last_log = 0, t0, t0

    def write_all(final=False):
        for n in nets:
            save(n["ema"], n["arch"], os.path.join(a.out, n["name"] + ".safetensors"),
                 {"steps": step, "batch": a.batch, "patches": step * a.batch, "samples": len(data), "final": final,
                  "trained_by": "docs/gpu/train.py (PyTorch %s)" % torch.__version__})

    while True:
        now = time.time()
        if now >= a.until:
            break
        frac = (now - t0) / span
        lr = a.lr * min(1.0, (now - t0) / a.warmup) * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * frac)))
        absorb()
        idx = torch.randint(0, len(data), (a.batch,), generator=g).to(dev)
        batch = augment(data[idx].float() / 255.0, g)  # [b, 2 + targets, c, h, w]
        # One sub-frame per sample for the burst nets; the middle one for the others.
        k = torch.randint(0, data.targets, (a.batch,), generator=g)
        if a.burst_ends > 0:
            # As `data.burst_ends`: a share of samples at the first or the last sub-frame.
            end = torch.rand(a.batch, generator=g) < a.burst_ends
            k = torch.where(end, torch.randint(0, 2, (a.batch,), generator=g) * (data.targets - 1), k)
        k = k.to(dev)
        rows = torch.arange(a.batch, device=dev)
        for n in nets:
            x = batch[:, n["cam"]].contiguous(memory_format=torch.channels_last)
            burst = n["arch"]["type"] == "burst_unet"
            y = (batch[rows, 2 + k] if burst else batch[:, 2 + data.targets // 2]).contiguous(memory_format=torch.channels_last)
            for pg in n["opt"].param_groups:
                pg["lr"] = lr
            with torch.autocast(dev.type, dtype=torch.bfloat16, enabled=amp):
                out = n["net"](x, data.times(k)) if burst else n["net"](x)
            loss = huber(out.float(), y)
            n["opt"].zero_grad(set_to_none=True)
            loss.backward()
            n["opt"].step()
            with torch.no_grad():
                # Warm-up of the average (as timm's): early steps do not hold on to the init.
                torch._foreach_lerp_(n["ema_p"], n["net_p"], 1 - min(a.ema, (1 + step) / (10 + step)))
                torch._foreach_copy_(n["ema_b"], n["net_b"])
            n["loss"] += loss.detach()
            n["n"] += 1
        step += 1
        if now - last_log >= 10 or step == 1:
            losses = [float(n["loss"]) / max(n["n"], 1) for n in nets]
            hw.writerow([step, round(now - t0, 1), len(data), f"{lr:.3g}"] + [f"{v:.6g}" for v in losses])
            hist.flush()
            log(f"step {step} ({step * a.batch / max(now - t0, 1e-9):.0f} patches/s per model), {len(data)} samples, lr {lr:.3g}, loss "
                + " ".join(f"{n['name']} {v:.5f}" for n, v in zip(nets, losses)), logf)
            for n in nets:
                n["loss"], n["n"] = 0.0, 0
            last_log = now
        if now - last_save >= a.save_every:
            write_all()
            last_save = now

    # BatchNorm statistics of the averaged weights: exact means over 50 training batches.
    for n in nets:
        ema = n["ema"]
        for m in ema.modules():
            if isinstance(m, torch.nn.BatchNorm2d):
                m.reset_running_stats()
                m.momentum = None
        ema.train()
        with torch.no_grad():
            gb = torch.Generator().manual_seed(a.seed + 1)
            for _ in range(50):
                idx = torch.randint(0, len(data), (a.batch,), generator=gb).to(dev)
                x = (data[idx, n["cam"]].float() / 255.0).contiguous(memory_format=torch.channels_last)
                t = data.times(torch.randint(0, data.targets, (a.batch,), generator=gb).to(dev))
                with torch.autocast(dev.type, dtype=torch.bfloat16, enabled=amp):
                    ema(x, t) if n["arch"]["type"] == "burst_unet" else ema(x)
        ema.eval()
    write_all(final=True)
    report = {"steps": step, "batch": a.batch, "patches_per_model": step * a.batch, "samples": len(data),
              "held_out": len(val), "seconds": round(time.time() - t0, 1), "gt_mismatch": pool.mismatch, "val": {}}
    with torch.no_grad():
        for n in nets:
            # Single-frame nets against the middle sub-frame; burst nets at every sub-frame.
            burst = n["arch"]["type"] == "burst_unet"
            ks = range(val.targets) if burst else [val.targets // 2]
            pin, pout = {k: [] for k in ks}, {k: [] for k in ks}
            for i in range(0, len(val), 64):
                v = val[i:i + 64].float() / 255.0
                x = v[:, n["cam"]].contiguous(memory_format=torch.channels_last)
                for k in ks:
                    y = v[:, 2 + k]
                    out = (n["ema"](x, torch.full((len(v),), (k + 0.5) / val.targets, device=dev)) if burst else n["ema"](x)).float()
                    pin[k].append(psnr(x, y))
                    pout[k].append(psnr(out, y))
            if len(val):
                at = {k: (torch.cat(pin[k]).mean().item(), torch.cat(pout[k]).mean().item()) for k in ks}
                pi, po = sum(v[0] for v in at.values()) / len(at), sum(v[1] for v in at.values()) / len(at)
                report["val"][n["name"]] = {"input_psnr": round(pi, 3), "output_psnr": round(po, 3), "gain": round(po - pi, 3)}
                if burst:
                    first, mid, last = at[0][1], at[val.targets // 2][1], at[val.targets - 1][1]
                    report["val"][n["name"]]["output_first_middle_last"] = [round(first, 3), round(mid, 3), round(last, 3)]
                log(f"{n['name']}: held out {len(val)} samples: input {pi:.2f} dB -> output {po:.2f} dB ({po - pi:+.2f})", logf)
    json.dump(report, open(os.path.join(a.out, "report.json"), "w"), indent=1)
    log(f"done: {step} steps x {a.batch} = {step * a.batch} patches per model from {len(data)} samples", logf)
    pool.stop = True


if __name__ == "__main__":
    main()
