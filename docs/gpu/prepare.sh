#!/usr/bin/env bash
# Packs what docs/gpu/run.sh needs on a GPU machine that reaches no registry, into GPU_DIR (keep
# it out of git: `echo /.gpu/ >> .git/info/exclude`):
#   pipeline    this repository's CLI built without FFmpeg (the `stills` source reads PNG itself),
#               so it runs on any x86-64 Linux with glibc
#   data.tar    the training crops that scripts/training-data.sh prepared, as JPEG (quality 93, no
#               chroma subsampling: a quarter of the PNG's size, so the whole set fits the 64 MiB a
#               call may carry; run.sh turns them back into PNG there), and the cut-outs (PNG)
#   init/shallow32-coded.safetensors   the shipped shallow model, which round 1 fine-tunes
#               (run.sh starts every net named in init/ from its file, the rest from scratch)
#
#   bash docs/gpu/prepare.sh [GPU_DIR=.gpu] [DATA=../data]
#   EVERY=2 bash docs/gpu/prepare.sh ...              # every other crop: with the shipped models in
#                                                   # the repository (30 MB) the whole set no longer fits
#                                                   # a call's 64 MiB; run.sh's --init models reads them there
#   bash docs/gpu/run.sh .gpu "$OUT" 470 32            # then, on the GPU machine
set -euo pipefail
cd "$(dirname "$0")/../.."
G=${1:-.gpu}
DATA=${2:-${DATA:-../data}}
mkdir -p "$G"
cargo build --release --no-default-features --target-dir target/no-ffmpeg --bin pipeline
cp target/no-ffmpeg/release/pipeline "$G/pipeline"
strip "$G/pipeline"
mkdir -p "$G/init"
target/release/pipeline export models/shallow32-coded -o "$G/init/shallow32-coded.safetensors"
rm -rf "$G/pack" && mkdir -p "$G/pack/photos/train"
mkdir -p "$G/pack/objects"
"${PYTHON:-.venv/bin/python}" - "$DATA" "$G/pack" <<'PY'
import glob, os, sys
from PIL import Image
data, pack = sys.argv[1:]
for f in sorted(glob.glob(f"{data}/photos/train/*.png"))[::int(os.environ.get("EVERY", "1"))]:
    out = os.path.join(pack, "photos/train", os.path.basename(f)[:-4] + ".jpg")
    Image.open(f).convert("RGB").save(out, "JPEG", quality=93, subsampling=0)
# Cut-outs at most 160 px on a side, above the largest the stills source draws them at (a 288 px
# frame times object_size 0.5; it scales them down again), resampled with premultiplied alpha.
for f in sorted(glob.glob(f"{data}/objects/*.png")):
    im = Image.open(f).convert("RGBA")
    s = min(1.0, 160 / max(im.size))
    if s < 1.0:
        im = im.convert("RGBa").resize((max(1, round(im.width * s)), max(1, round(im.height * s))), Image.LANCZOS).convert("RGBA")
    im.save(os.path.join(pack, "objects", os.path.basename(f)), optimize=True)
PY
tar cf "$G/data.tar" -C "$G/pack" photos objects
rm -rf "$G/pack"
du -sh "$G"/*
