"""Throughput of the Python dataset against reading the same pairs from shards.

In one run, on one 1280x720 240 fps clip (made here with FFmpeg's mandelbrot source):
  - CodedBlurDataset: decode, blur, noise, patches in process (pairs/s, as a training loop sees them);
  - webdataset 1.x reading the shards `pipeline generate` wrote for the same clip and seed
    (PNG decode to uint8 arrays), the usual way PyTorch users consume the generator today;
  - `pipeline generate` itself (pairs/s written to shards), for scale.
Medians of REPEATS runs. Needs the package built into the running Python and `webdataset`.

Usage: python benches/python_dataset.py [SECONDS=1] [REPEATS=3]
"""
import glob
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

import pipeline

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
EXE = os.environ.get("PIPELINE_BIN", os.path.join(ROOT, "target", "release", "pipeline"))


def timed(f):
    t = time.perf_counter()
    n = f()
    return n, time.perf_counter() - t


def main():
    seconds = float(sys.argv[1]) if len(sys.argv) > 1 else 1.0
    repeats = int(sys.argv[2]) if len(sys.argv) > 2 else 3
    import webdataset as wds

    tmp = tempfile.mkdtemp(prefix="pydataset-bench-")
    clip = os.path.join(tmp, "clip.mp4")
    subprocess.run(["ffmpeg", "-v", "error", "-y", "-f", "lavfi", "-i", f"mandelbrot=size=1280x720:rate=240,format=yuv420p",
                    "-t", str(seconds), "-c:v", "libx264", "-preset", "veryfast", "-crf", "18", clip], check=True)
    rows = {"generate (shards written)": [], "webdataset (shards read)": [], "CodedBlurDataset (in process)": []}
    n_pairs = None
    for r in range(repeats):
        out = os.path.join(tmp, f"out{r}")
        n, t = timed(lambda: (subprocess.run([EXE, "generate", clip, "-o", out, "--progress", "never"], check=True,
                                             capture_output=True), json.load(open(os.path.join(out, "report.json")))["samples"])[1])
        rows["generate (shards written)"].append(n / t)
        urls = sorted(glob.glob(os.path.join(out, "*.tar")))
        ds = wds.WebDataset(urls, shardshuffle=False).decode("rgb8").to_tuple("lq.png", "gt.png", "json")
        n, t = timed(lambda: sum(1 for _ in ds))
        rows["webdataset (shards read)"].append(n / t)
        n_pairs = n
        n, t = timed(lambda: sum(1 for _ in pipeline.CodedBlurDataset([clip])))
        assert n == n_pairs, (n, n_pairs)
        rows["CodedBlurDataset (in process)"].append(n / t)
    base = statistics.median(rows["webdataset (shards read)"])
    print(f"{n_pairs} pairs of 128x128 from a {seconds:g} s 1280x720 240 fps clip, medians of {repeats}, {os.cpu_count()} cores")
    print(f"{'':32} {'pairs/s':>9} {'runs':>26} {'/ webdataset':>13}")
    for k, v in rows.items():
        m = statistics.median(v)
        print(f"{k:32} {m:9.1f} {', '.join(f'{x:.1f}' for x in v):>26} {m / base:12.2f}x")


if __name__ == "__main__":
    main()
