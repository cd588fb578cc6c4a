#!/usr/bin/env bash
# Trains the shipped models (models/README.md) on the shards scripts/training-data.sh makes: a U-Net
# per camera on identical data, seeds, order and steps (25,000 x 8 = 200,000 patches each), one
# thread each at the lowest priority, so two run side by side on a 2-core machine. Each run
# checkpoints every 250 steps; run the same command again to resume where it stopped.
#
#   bash scripts/train-models.sh phase_coded 16        # or: conventional 16, phase_coded 32, ...
#   DATA=../data RUNS=../runs STEPS=25000 bash scripts/train-models.sh conventional 16
#   bash scripts/train-models.sh phase_coded shallow   # the shallow model (32 filters)
#   INIT=models/unet16-coded STEPS=5000 LR=5e-4 NAME=ft bash scripts/train-models.sh phase_coded 16
#                                                   # fine-tuning a shipped model: a run of its own
#                                                   # (STEPS new steps, a schedule peaking at LR)
#   SETS="7 9 11 13 9-added" ...                    # shard sets to train on ($DATA/shards/CAM-nSET)
set -euo pipefail
cd "$(dirname "$0")/.."
CAM=${1:?camera: phase_coded or conventional}
WIDTH=${2:-16}
DATA=${DATA:-../data}
RUNS=${RUNS:-../runs}
STEPS=${STEPS:-25000}
LR=${LR:-1e-3}
WARMUP=${WARMUP:-200}
PIPELINE=${PIPELINE:-target/release/pipeline}
"$PIPELINE" train --help >/dev/null 2>&1 || { echo "$0: $PIPELINE cannot train: build it with cargo build --release --features train" >&2; exit 2; }
shards=""
for n in ${SETS:-7 9 11 13}; do shards="$shards${shards:+, }\"$DATA/shards/$CAM-n$n/*.tar\""; done
if [ "$WIDTH" = shallow ]; then
  config=pipelines/train-shallow.toml; name=shallow32-$CAM; model=()
else
  config=pipelines/train.toml; name=unet$WIDTH-$CAM; model=(--set "model.base=$WIDTH")
fi
[ -n "${NAME:-}" ] && name="$name-$NAME"
init=(); [ -n "${INIT:-}" ] && init=(--set "init=\"$INIT\"")
dir="$RUNS/$name"
resume=(); [ -f "$dir/latest.json" ] && resume=(--resume)
RAYON_NUM_THREADS=${THREADS:-1} exec nice -n 19 "$PIPELINE" train --config "$config" "${resume[@]}" --progress never "${model[@]}" "${init[@]}" \
  --set "data.shards=[$shards]" --set data.val_fraction=0.1 --set data.shuffle_buffer=8192 \
  --set optim.steps="$STEPS" --set optim.lr="$LR" --set optim.lr_min_factor=0.05 --set optim.warmup_steps="$WARMUP" \
  --set validate.every=500 --set validate.max_samples=512 \
  --set output.checkpoint_every=250 --set output.average_last=8 --set "output.dir=\"$dir\""
