#!/usr/bin/env bash
# The shipped single-frame U-Net 32 pair fine-tuned on captures like a prototype's
# (pipelines/train-realistic.toml: hand-held shake to 60 px of spread, shot and read noise, an RGGB
# mosaic), the coded and the conventional model on identical data, seeds and steps, each from the
# shipped model of its camera (`init`). One thread each at the lowest priority, so the two run side
# by side on a 2-core machine; checkpoints every 100 steps, and the same command again resumes.
# MIX=hand keeps the paper's ideal read-out (pipelines/train-data.toml, AWGN) and adds only the
# hand-held shake, the same share: the data for the large shakes without a change of sensor.
#
#   bash scripts/train-realistic.sh shards              # both cameras' shards ($DATA/shards/realistic-*)
#   bash scripts/train-realistic.sh phase_coded         # one run ($RUNS/realistic-unet32-phase_coded)
#   DATA=../data RUNS=../runs STEPS=500 bash scripts/train-realistic.sh conventional
#   MIX=hand bash scripts/train-realistic.sh shards     # $DATA/shards/hand-*, runs in $RUNS/hand-unet32-*
#
# Needs the photographs of scripts/training-data.sh (STEP=photos bash scripts/training-data.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
WHAT=${1:?shards, phase_coded or conventional}
DATA=${DATA:-../data}
RUNS=${RUNS:-../runs}
STEPS=${STEPS:-500}
LR=${LR:-1e-4}
PIPELINE=${PIPELINE:-target/release/pipeline}
MIX=${MIX:-realistic}
PER_WINDOW=${PER_WINDOW:-2}
case "$MIX" in
  realistic) config=pipelines/train-realistic.toml; mix=() ;;
  hand) config=pipelines/train-data.toml; mix=(--set sources.stills.motion.weights.hand=0.35) ;;
  *) echo "train-realistic.sh: MIX=$MIX: expected realistic or hand" >&2; exit 2 ;;
esac
"$PIPELINE" train --help >/dev/null 2>&1 || { echo "$0: $PIPELINE cannot train: build it with cargo build --release --features train" >&2; exit 2; }

# Shards: 4 windows of 9 per photograph, PER_WINDOW patches each (6,288 samples per camera from the
# 786 crops at 2); the two cameras side by side, one thread each.
if [ "$WHAT" = shards ]; then
  for cam in phase_coded conventional; do
    d="$DATA/shards/$MIX-$cam"
    [ -f "$d/manifest.json" ] && continue
    RAYON_NUM_THREADS=1 nice -n 10 "$PIPELINE" run "$config" -o "$d" --progress never --set seed=${SEED:-41} "${mix[@]}" \
      --set sources.stills.frames=36 --set transforms.patches.per_window="$PER_WINDOW" --set transforms.blur.threads=1 \
      --set transforms.blur.camera.type=$cam \
      --set "sources.stills.paths=[\"$DATA/photos/train\"]" --set "sources.stills.motion.object_paths=[\"$DATA/objects\"]" &
  done
  wait
  exit 0
fi

case "$WHAT" in
  phase_coded) init=${INIT:-models/unet32-coded} ;;
  conventional) init=${INIT:-models/unet32-conventional} ;;
  *) echo "train-realistic.sh: $WHAT: expected shards, phase_coded or conventional" >&2; exit 2 ;;
esac
dir="$RUNS/$MIX-unet32-$WHAT"
resume=(); [ -f "$dir/latest.json" ] && resume=(--resume)
RAYON_NUM_THREADS=${THREADS:-1} exec nice -n 19 "$PIPELINE" train --config pipelines/train.toml "${resume[@]}" --progress never \
  --set model.base=32 --set "init=\"$init\"" \
  --set "data.shards=[\"$DATA/shards/$MIX-$WHAT/*.tar\"]" --set data.val_fraction=0.1 --set data.shuffle_buffer=1024 \
  --set optim.steps="$STEPS" --set optim.lr="$LR" --set optim.lr_min_factor=0.1 --set optim.warmup_steps=20 \
  --set validate.every=100 --set validate.max_samples=128 \
  --set output.checkpoint_every=100 --set output.average_last=3 --set "output.dir=\"$dir\""
