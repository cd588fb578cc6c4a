#!/usr/bin/env python3
"""What each camera keeps of a moving scene: the best linear reconstruction when the motion is known.

A check of the physics apart from any network. For a steady motion of v px per frame over a window
of N frames, each camera's window image is the sharp linear image convolved with one kernel per
colour channel, K_c = mean over t of PSF_t,c shifted by (t - (N-1)/2) v (the sub-frame PSFs come
from `pipeline psf --window N`; the motion, blur, noise and reconstruction are computed here with
numpy, not by `pipeline generate`). The image is then sRGB-encoded, given AWGN of sigma on the
0-255 scale and quantised, as `pipeline generate` does. The reconstruction is the linear minimum
mean-square-error (Wiener) estimate that knows the kernels, the noise level and the sharp image's
3x3 cross-channel power spectrum (averaged over rings of equal frequency): per frequency
    x = S K^H (K S K^H + s2 I)^-1 y,
so a zero of one channel's kernel is filled from the others where the channels are correlated, as
they are in real photographs. No network can do better than the best *non-linear* estimator, which
this is not, but it is what the measurements themselves carry when the motion is known: if a camera
loses here, a network has to beat linear estimation by the difference to win. Circular convolution
on 256 px crops, so the model is exact at the borders.

    python3 scripts/known-motion-bound.py [SKIMAGE_DATA_DIR]          # prints two Markdown tables
    PSF_ARGS="--airy-radius-px 1.17" python3 scripts/known-motion-bound.py   # other optics (flags of `pipeline psf`)

Needs numpy and Pillow, ffmpeg-free; the held-out test photographs of docs/eval.md (Debian's
mate-backgrounds, GPL-2+; scikit-image's coffee, CC0); target/release/pipeline (or $PIPELINE).
"""
import os
import subprocess
import sys
import tempfile

import numpy as np
from PIL import Image

PIPELINE = os.environ.get("PIPELINE", "target/release/pipeline")
BG = "/usr/share/backgrounds/mate/nature"
SIZE = 256
CAMERAS = ["conventional", "focus_sweep", "phase_coded"]
SPEEDS = [0, 1, 2, 3, 4, 6, 8]  # px per frame
ANGLES = [0, 45, 90, 135]  # degrees; the opposite directions mirror these


def to_linear(e):
    return np.where(e <= 0.04045, e / 12.92, ((e + 0.055) / 1.055) ** 2.4)


def to_srgb(x):
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)


def quantise(e):
    return np.round(np.clip(e, 0.0, 1.0) * 255.0)


def psnr8(a, b):
    return 10 * np.log10(255.0**2 / np.mean((a - b) ** 2))


def photo(path):
    """The photo at the test clips' 720p scale, a centred SIZE x SIZE crop, linear RGB (H, W, 3)."""
    im = Image.open(path).convert("RGB")
    s = min(720, min(im.size)) / min(im.size)
    im = im.resize((round(im.size[0] * s), round(im.size[1] * s)), Image.LANCZOS)
    x0, y0 = (im.size[0] - SIZE) // 2, (im.size[1] - SIZE) // 2
    return to_linear(np.asarray(im.crop((x0, y0, x0 + SIZE, y0 + SIZE)), dtype=np.float64) / 255.0)


def psfs(camera, n):
    with tempfile.TemporaryDirectory() as d:
        out = os.path.join(d, "k.npy")
        args = [PIPELINE, "psf", "--camera", camera, "--window", str(n), "-o", out] + os.environ.get("PSF_ARGS", "").split()
        subprocess.run(args, check=True, capture_output=True)
        return np.load(out).astype(np.float64)  # (N, k, k, 3), each sums to 1


def spectra(k):
    """FFTs on the SIZE grid of each sub-frame PSF, centred on the origin: (N, SIZE, SIZE, 3)."""
    n, h, w, _ = k.shape
    pad = np.zeros((n, SIZE, SIZE, 3))
    pad[:, :h, :w] = k
    pad = np.roll(pad, (-(h // 2), -(w // 2)), axis=(1, 2))
    return np.fft.fft2(pad, axes=(1, 2))


def window_kernel(p, v):
    """K_c(f) of a steady motion v = (vx, vy) px per frame: (SIZE, SIZE, 3)."""
    n = p.shape[0]
    f = np.fft.fftfreq(SIZE)
    fy, fx = np.meshgrid(f, f, indexing="ij")
    k = np.zeros(p.shape[1:], dtype=complex)
    for t in range(n):
        s = t - (n - 1) / 2
        k += p[t] * np.exp(-2j * np.pi * (fx * v[0] * s + fy * v[1] * s))[..., None]
    return k / n


def ring_covariance(X):
    """The 3x3 cross-spectrum X_c conj(X_d) averaged over rings of equal |f|: (SIZE, SIZE, 3, 3)."""
    f = np.fft.fftfreq(SIZE) * SIZE
    r = np.round(np.hypot(*np.meshgrid(f, f, indexing="ij"))).astype(int)
    outer = X[..., :, None] * np.conj(X[..., None, :])
    cov = np.zeros((r.max() + 1, 3, 3), dtype=complex)
    cnt = np.bincount(r.ravel())
    for c in range(3):
        for d in range(3):
            cov[:, c, d] = np.bincount(r.ravel(), outer[..., c, d].real.ravel()) + 1j * np.bincount(r.ravel(), outer[..., c, d].imag.ravel())
    return (cov / cnt[:, None, None])[r]


def wiener(Y, K, S, s2):
    """x = S K^H (K S K^H + s2 I)^-1 y per frequency (K diagonal over channels)."""
    A = K[..., :, None] * S * np.conj(K[..., None, :]) + s2 * np.eye(3)
    b = np.linalg.solve(A, Y[..., None])[..., 0]
    return np.einsum("...cd,...d->...c", S, np.conj(K) * b)


def reconstruct(x, X, S, K, noise):
    """Blurred input and reconstruction PSNR of one camera, one motion, one noise draw."""
    sharp8 = quantise(to_srgb(x))
    y = np.real(np.fft.ifft2(K * X, axes=(0, 1)))
    y8 = quantise(to_srgb(y) + noise)
    z = to_linear(y8 / 255.0)
    # Noise and quantisation as they land in linear light (the estimator is told their power).
    s2 = np.mean((z - y) ** 2) * SIZE * SIZE
    xr = np.real(np.fft.ifft2(wiener(np.fft.fft2(z, axes=(0, 1)), K, S, s2), axes=(0, 1)))
    return psnr8(y8, sharp8), psnr8(quantise(to_srgb(xr)), sharp8)


def table(title, keys, rows, first):
    print(f"\n{title}\n")
    head = "| " + " | ".join(first) + " | " + " | ".join(CAMERAS) + " | coded - conventional |"
    print(head)
    print("|" + "---|" * (head.count("|") - 1))
    for key in keys:
        cells, rec = [], {}
        for cam in CAMERAS:
            b, r = np.mean(rows[key + (cam,)], axis=0)
            rec[cam] = r
            cells.append(f"{b:.2f} -> {r:.2f}")
        print("| " + " | ".join(str(k) for k in key) + " | " + " | ".join(cells) + f" | {rec['phase_coded'] - rec['conventional']:+.2f} |")


def main():
    sk = sys.argv[1] if len(sys.argv) > 1 else None
    if sk is None:
        import skimage.data

        sk = os.path.dirname(skimage.data.__file__)
    photos = [f"{BG}/Storm.jpg", f"{BG}/YellowFlower.jpg", f"{BG}/Wood.jpg", f"{sk}/coffee.png"]
    # The pans of the test clips (scripts/training-data.sh), px per frame, one per photo.
    clip_v = [(3, 1), (-2, 2), (5, 0), (1, -3)]
    rng = np.random.default_rng(0)
    P = {(c, n): spectra(psfs(c, n)) for c in CAMERAS for n in (7, 9, 11, 13)}
    images = []
    for path in photos:
        x = photo(path)
        X = np.fft.fft2(x, axes=(0, 1))
        images.append((x, X, ring_covariance(X)))
    # 1. Steady motions of every speed in four directions, N = 9.
    speeds = {}
    for x, X, S in images:
        for speed in SPEEDS:
            for a in ANGLES if speed else [0]:
                v = (speed * np.cos(np.radians(a)), speed * np.sin(np.radians(a)))
                for sigma in (1, 3):
                    noise = rng.standard_normal(x.shape) * sigma / 255.0  # the same noise for every camera
                    for cam in CAMERAS:
                        speeds.setdefault((speed, speed * 8, sigma, cam), []).append(reconstruct(x, X, S, window_kernel(P[(cam, 9)], v), noise))
    # 2. The test clips' own motions, Table 1's N and sigma.
    clips = {}
    for (x, X, S), v in zip(images, clip_v):
        for n in (7, 9, 11, 13):
            for sigma in (0, 1, 2, 3):
                noise = rng.standard_normal(x.shape) * sigma / 255.0
                for cam in CAMERAS:
                    r = reconstruct(x, X, S, window_kernel(P[(cam, n)], v), noise)
                    clips.setdefault((n, "0-3", cam), []).append(r)
    print("PSNR dB on 8-bit sRGB of 256 px crops of the four held-out photographs (docs/eval.md): "
          "blurred input -> known-motion Wiener reconstruction")
    table("Steady motion, window N = 9, mean over 4 photos x 4 directions", [k[:3] for k in speeds if k[3] == CAMERAS[0]], speeds,
          ["px per frame", "px per window", "sigma"])
    table("The test clips' pans (3,1), (-2,2), (5,0), (1,-3) px per frame, mean over the 4 clips and sigma 0 to 3",
          [k[:2] for k in clips if k[2] == CAMERAS[0]], clips, ["N", "sigma"])


if __name__ == "__main__":
    main()
