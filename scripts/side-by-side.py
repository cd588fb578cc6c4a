"""One picture of the same test windows through both cameras: blurred coded | coded model |
blurred conventional | conventional model | sharp, a row per example, from the `examples/` that
`pipeline eval` wrote for each camera (scripts/eval-models.sh runs both on the same windows).

    python3 scripts/side-by-side.py ../ev/gpu2/shake-phase_coded ../ev/gpu2/shake-conventional docs/figures/shake-side-by-side.jpg [ROWS]

PSNR (RGB, dB) in the labels is recomputed on the 8-bit panels against the sharp panel. Needs
NumPy and Pillow.
"""

import glob
import os
import sys

import numpy as np
from PIL import Image, ImageDraw

coded_dir, conv_dir, out = sys.argv[1:4]
rows = int(sys.argv[4]) if len(sys.argv) > 4 else 3
P, GAP, LABEL = 192, 4, 14  # eval's example layout: three 192 px panels, 4 px apart, a 14 px label row


def panels(path):
    im = np.asarray(Image.open(path).convert("RGB"))
    return [im[LABEL:LABEL + P, i * (P + GAP):i * (P + GAP) + P] for i in range(3)]


def psnr(a, b):
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)
    return 10 * np.log10(255.0**2 / max(mse, 1e-10))


names = sorted(os.path.basename(p) for p in glob.glob(f"{coded_dir}/examples/*.png"))
names = [n for n in names if os.path.exists(f"{conv_dir}/examples/{n}")][:rows]
if not names:
    raise SystemExit(f"no example names both {coded_dir}/examples and {conv_dir}/examples hold")
W, H = 5 * P + 4 * GAP, len(names) * (P + 2 * LABEL + GAP)
canvas = Image.new("RGB", (W, H), "white")
draw = ImageDraw.Draw(canvas)
for r, n in enumerate(names):
    ci, co, sharp = panels(f"{coded_dir}/examples/{n}")
    vi, vo, sharp2 = panels(f"{conv_dir}/examples/{n}")
    y = r * (P + 2 * LABEL + GAP)
    draw.text((2, y), n[:-4], fill="black")
    for i, (img, label) in enumerate([(ci, "coded input"), (co, "coded U-Net"), (vi, "conventional input"),
                                      (vo, "conventional U-Net"), (sharp, "sharp")]):
        x = i * (P + GAP)
        canvas.paste(Image.fromarray(img), (x, y + 2 * LABEL))
        text = label if img is sharp else f"{label} {psnr(img, sharp):.1f} dB"
        draw.text((x + 2, y + LABEL), text, fill="black")
canvas.save(out, quality=90)  # JPEG for the repository; PNG ignores quality
print(f"{len(names)} rows -> {out}")
