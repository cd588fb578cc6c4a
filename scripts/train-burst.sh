#!/usr/bin/env bash
# The burst pair (models/README.md): burst shards at N = 9 for each camera (the same photographs,
# motions, noise and patches; only the camera differs), then a burst U-Net per camera on identical
# data, seeds, order and steps, each started from the shipped single-frame U-Net of its camera
# (`init`: the same weights, the time conditioning at zero). One thread each at the lowest
# priority, so the two run side by side on a 2-core machine; checkpoints every 250 steps, and the
# same command again resumes where a run stopped.
#
#   bash scripts/train-burst.sh shards                 # both cameras' burst shards ($DATA/shards/burst-*)
#   bash scripts/train-burst.sh phase_coded            # one run ($RUNS/burst-unet32-phase_coded)
#   DATA=../data RUNS=../runs STEPS=20000 WIDTH=32 bash scripts/train-burst.sh conventional
#   INIT=models/burst-unet32-coded STEPS=1500 LR=2.4e-4 WARMUP=20 bash scripts/train-burst.sh phase_coded
#                                                      # continue from a shipped burst model
#   LEVELS=4 INIT=models/burst-unet32-coded bash scripts/train-burst.sh phase_coded
#                                                      # told the time on every decoder level
#                                                      # ($RUNS/burst-unet32-film4-phase_coded)
#   ENDS=0.5 INIT=models/burst-unet32-coded bash scripts/train-burst.sh phase_coded
#                                                      # half the samples at the first or last time
#                                                      # ($RUNS/burst-unet32-ends0.5-phase_coded)
#
# Needs the photographs of scripts/training-data.sh (STEP=photos bash scripts/training-data.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
WHAT=${1:?shards, phase_coded or conventional}
DATA=${DATA:-../data}
RUNS=${RUNS:-../runs}
STEPS=${STEPS:-20000}
WIDTH=${WIDTH:-32}
LR=${LR:-3e-4}
WARMUP=${WARMUP:-200}
LEVELS=${LEVELS:-1}
ENDS=${ENDS:-0}
PIPELINE=${PIPELINE:-target/release/pipeline}
"$PIPELINE" train --help >/dev/null 2>&1 || { echo "$0: $PIPELINE cannot train: build it with cargo build --release --features train" >&2; exit 2; }

# Burst shards: 4 windows of 9 per photograph, 2 patches each (6,300 samples per camera from the
# 786 crops, each with 9 targets: about 1.1 GB); the two cameras side by side, one thread each.
if [ "$WHAT" = shards ]; then
  for cam in phase_coded conventional; do
    d="$DATA/shards/burst-$cam-n9"
    [ -f "$d/manifest.json" ] && continue
    RAYON_NUM_THREADS=1 nice -n 10 "$PIPELINE" run pipelines/train-data.toml -o "$d" --progress never --set seed=${SEED:-31} \
      --set transforms.blur.window=9 --set transforms.blur.burst=true --set sources.stills.frames=36 \
      --set transforms.blur.camera.type=$cam --set sinks.shards.prefix=burst-n9 --set transforms.patches.per_window=2 \
      --set transforms.blur.threads=1 \
      --set "sources.stills.paths=[\"$DATA/photos/train\"]" --set "sources.stills.motion.object_paths=[\"$DATA/objects\"]" &
  done
  wait
  exit 0
fi

case "$WHAT" in
  phase_coded) init=${INIT:-models/unet$WIDTH-coded} ;;
  conventional) init=${INIT:-models/unet$WIDTH-conventional} ;;
  *) echo "train-burst.sh: $WHAT: expected shards, phase_coded or conventional" >&2; exit 2 ;;
esac
name="burst-unet$WIDTH"; [ "$LEVELS" = 1 ] || name="$name-film$LEVELS"; [ "$ENDS" = 0 ] || name="$name-ends$ENDS"
dir="$RUNS/$name-$WHAT"
resume=(); [ -f "$dir/latest.json" ] && resume=(--resume)
RAYON_NUM_THREADS=${THREADS:-1} exec nice -n 19 "$PIPELINE" train --config pipelines/train.toml "${resume[@]}" --progress never \
  --set model.type='"burst_unet"' --set model.base="$WIDTH" --set model.levels="$LEVELS" --set "init=\"$init\"" \
  --set "data.shards=[\"$DATA/shards/burst-$WHAT-n9/*.tar\"]" --set data.val_fraction=0.1 --set data.shuffle_buffer=1024 --set data.burst_ends="$ENDS" \
  --set optim.steps="$STEPS" --set optim.lr="$LR" --set optim.lr_min_factor=0.05 --set optim.warmup_steps="$WARMUP" \
  --set validate.every=500 --set validate.max_samples=256 \
  --set output.checkpoint_every=250 --set output.average_last=4 --set "output.dir=\"$dir\""
