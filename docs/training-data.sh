#!/usr/bin/env bash
# Makes the training photos, the held-out test clips and the training shards of the shipped
# models (models/README.md). Needs: ffmpeg, the Debian package mate-backgrounds (GPL-2+ photos),
# and scikit-image's sample photos (public domain / CC0; `pip install scikit-image`).
#   bash docs/training-data.sh [SKIMAGE_DATA_DIR] [OUT=data]
set -euo pipefail
SK=${1:-$(python3 -c 'import skimage.data, os; print(os.path.dirname(skimage.data.__file__))')}
OUT=${2:-data}
BG=/usr/share/backgrounds/mate/nature
PIPELINE=${PIPELINE:-target/release/pipeline}
mkdir -p "$OUT/photos/train" "$OUT/test"
# Held apart by source photo, never by patch: Storm, YellowFlower, Wood and coffee are test only.
TRAIN=("$BG/Aqua.jpg" "$BG/Blinds.jpg" "$BG/Dune.jpg" "$BG/FreshFlower.jpg" "$BG/Garden.jpg" "$BG/GreenMeadow.jpg"
       "$BG/LadyBird.jpg" "$BG/RainDrops.jpg" "$BG/TwoWings.jpg" "$SK/astronaut.png" "$SK/chelsea.png" "$SK/rocket.jpg"
       "$SK/grass.png" "$SK/gravel.png" "$SK/brick.png")
TEST=("$BG/Storm.jpg" "$BG/YellowFlower.jpg" "$BG/Wood.jpg" "$SK/coffee.png")
# Ten 384x288 crops per training photo: even ones at 720p scale (short side 720, or the photo's
# own if smaller), odd ones at the photo's full resolution (finer texture per pixel).
for f in "${TRAIN[@]}"; do
  b=$(basename "${f%.*}")
  for i in 0 1 2 3 4 5 6 7 8 9; do
    fx=$(( (i * 37) % 10 )); fy=$(( (i * 53) % 10 ))
    scale="scale=-2:'min(720,ih)',"; [ $((i % 2)) -eq 1 ] && scale=""
    ffmpeg -v error -y -i "$f" -vf "${scale}format=rgb24,crop=384:288:(iw-384)*$fx/9:(ih-288)*$fy/9" -frames:v 1 "$OUT/photos/train/${b}_$i.png"
  done
done
# Test clips: each held-out photo panned by the camera at 240 fps (real photographs, real
# FFmpeg-encoded video; 1 to 5 px per frame in four directions).
k=0
for f in "${TEST[@]}"; do
  b=$(basename "${f%.*}")
  case $k in
    0) X='100+3*n'; Y='60+1*n' ;;
    1) X='400-2*n'; Y='80+2*n' ;;
    2) X='200+5*n'; Y='150' ;;
    *) X='120+1*n'; Y='200-3*n' ;;
  esac
  ffmpeg -v error -y -loop 1 -framerate 240 -i "$f" -vf "scale=-2:'min(720,ih)',crop=320:240:'$X':'$Y',format=yuv420p" -r 240 -frames:v 60 \
    -c:v libx264 -crf 12 "$OUT/test/$b-pan-240fps.mp4"
  k=$((k + 1))
done
# Training shards: the same clips through the coded and the conventional camera.
"$PIPELINE" run pipelines/train-data.toml -o "$OUT/coded" --set "sources.stills.paths=[\"$OUT/photos/train\"]"
"$PIPELINE" run pipelines/train-data.toml -o "$OUT/conventional" --set "sources.stills.paths=[\"$OUT/photos/train\"]" \
  --set transforms.blur.camera.type=conventional
# Windows of 7, 11 and 13 frames too (models/README.md): $WINDOWS windows per clip (8 for the U-Net 32
# runs, 7,200 pairs each; 4 for the fine-tuning of the shipped models, 3,600), a seed of their own per
# N (other motions), the same for both cameras.
WINDOWS=${WINDOWS:-8}
for n in 7 11 13; do
  for cam in phase_coded conventional; do
    d="$OUT/conventional-n$n"; [ $cam = phase_coded ] && d="$OUT/coded-n$n"
    "$PIPELINE" run pipelines/train-data.toml -o "$d" --set "sources.stills.paths=[\"$OUT/photos/train\"]" \
      --set seed=$((11 + n)) --set sources.stills.frames=$((WINDOWS * n)) --set transforms.blur.window=$n \
      --set transforms.blur.camera.type=$cam --set sinks.shards.prefix=n$n
  done
done
