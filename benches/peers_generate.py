"""SciPy and PyTorch peers of `pipeline generate`'s whole-frame coded blur, for `pipeline bench
generate`: the same physics written the way one would in Python, timed on the same clip with the
same thread count. Prints one JSON object.

Per exposure window of N consecutive frames (stride N, as pipelines/generate.toml): decode (the
ffmpeg CLI, rgb24), linearise (sRGB, a lookup table), then for every sub-frame t and channel c the
FFT of the frame times the spectrum of kernel t (`pipeline psf --window N`, spectra computed once),
summed over the window before one inverse per channel; the mean over the window, cropped to the
frame, sRGB-encoded and quantised to 8 bits (what the noise stage of sigma 0 hands on). float32
throughout. Nothing is written (the bench's `full frame` mode writes nothing either).

Usage: python3 benches/peers_generate.py scipy|torch CLIP WIDTH HEIGHT KERNELS.npy THREADS
Skipped by `pipeline bench generate` when the framework is not installed.
"""
import json
import subprocess
import sys
import time

import numpy as np


def srgb_lut():
    v = np.arange(256, dtype=np.float64) / 255.0
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4).astype(np.float32)


def encode(y):
    y = np.clip(y, 0.0, 1.0)
    e = np.where(y <= 0.0031308, 12.92 * y, 1.055 * np.power(y, 1.0 / 2.4, dtype=np.float32) - 0.055)
    return (e * 255.0 + 0.5).astype(np.uint8)


def frames(clip, w, h):
    """The clip's frames as (h, w, 3) uint8, decoded by the ffmpeg CLI."""
    p = subprocess.Popen(["ffmpeg", "-v", "error", "-i", clip, "-f", "rawvideo", "-pix_fmt", "rgb24", "-"], stdout=subprocess.PIPE)
    size = w * h * 3
    while True:
        b = p.stdout.read(size)
        if len(b) < size:
            break
        yield np.frombuffer(b, np.uint8).reshape(h, w, 3)
    p.wait()


def main():
    peer, clip, w, h, kernels, threads = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), sys.argv[5], int(sys.argv[6])
    k = np.load(kernels)  # (N, kh, kw, 3), each sums to 1
    n, kh, kw, _ = k.shape
    lut = srgb_lut()
    if peer == "scipy":
        import scipy
        import scipy.fft as fft

        version = scipy.__version__
        hp, wp = fft.next_fast_len(h + kh - 1, real=True), fft.next_fast_len(w + kw - 1, real=True)
        spec = [[fft.rfft2(k[t, :, :, c], s=(hp, wp), workers=threads) for c in range(3)] for t in range(n)]

        def window(xs):
            acc = [None] * 3
            for t, x in enumerate(xs):
                for c in range(3):
                    f = fft.rfft2(x[:, :, c], s=(hp, wp), workers=threads) * spec[t][c]
                    acc[c] = f if acc[c] is None else acc[c] + f
            return np.stack([fft.irfft2(a, s=(hp, wp), workers=threads)[kh // 2 : kh // 2 + h, kw // 2 : kw // 2 + w] for a in acc], -1) / n

    elif peer == "torch":
        import torch

        torch.set_num_threads(threads)
        version = torch.__version__
        hp, wp = h + kh - 1, w + kw - 1
        hp, wp = hp + hp % 2, wp + wp % 2
        kt = torch.from_numpy(np.ascontiguousarray(k.transpose(0, 3, 1, 2)))  # (N, 3, kh, kw)
        spec = torch.fft.rfft2(kt, s=(hp, wp))

        def window(xs):
            with torch.no_grad():
                x = torch.from_numpy(np.stack(xs).transpose(0, 3, 1, 2).copy())  # (N, 3, h, w)
                acc = (torch.fft.rfft2(x, s=(hp, wp)) * spec).sum(0)
                y = torch.fft.irfft2(acc, s=(hp, wp))[:, kh // 2 : kh // 2 + h, kw // 2 : kw // 2 + w] / n
                return y.permute(1, 2, 0).numpy()

    else:
        sys.exit(f"unknown peer {peer!r}: scipy or torch")

    t0 = time.perf_counter()
    windows, xs = 0, []
    for f in frames(clip, w, h):
        xs.append(lut[f])
        if len(xs) == n:
            encode(window(xs))
            windows, xs = windows + 1, []
    secs = time.perf_counter() - t0
    print(json.dumps({"peer": peer, "version": version, "threads": threads, "windows": windows, "subframes": windows * n, "seconds": secs, "subframes_per_s": windows * n / secs}))


if __name__ == "__main__":
    main()
