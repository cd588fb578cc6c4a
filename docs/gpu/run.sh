#!/usr/bin/env bash
# Trains the U-Net pair and the shallow model on a GPU machine in one go: its CPU cores render
# training shards with `pipeline run pipelines/train-data.toml` (both cameras from the same seeds,
# one pass per seed over every photograph, N cycling 9, 7, 11, 13) while docs/gpu/train.py trains
# on what has been written so far. Everything it needs travels in GPU_DIR (docs/gpu/prepare.sh
# makes it here: a `pipeline` built without FFmpeg, the photographs and cut-outs, and in init/
# the weights of the nets that do not start from scratch); nothing is fetched there.
#
#   bash docs/gpu/run.sh GPU_DIR OUT SECONDS [NETS]     # e.g. .gpu "$OUT" 500
#   SEED0=2000 TRAIN_ARGS="--lr 3e-4" bash docs/gpu/run.sh ...   # a second round: GPU_DIR/init holds the
#                                                   # first round's NAME.safetensors, new seeds give new data
#   SEED0=3000 TRAIN_ARGS="--init models" ...       # or start from the shipped models (they travel with the tree)
#   (NETS: docs/gpu/train.py --nets; by default U-Net 32 for each camera, U-Net 16 coded for the
#   width comparison at equal patches, the shallow model coded)
#   BURST=1 TRAIN_ARGS="--init models --lr 3e-4" bash docs/gpu/run.sh GPU_DIR OUT 500
#                                                   # the burst pair: burst shards (N = 9, a target
#                                                   # per sub-frame), from the shipped burst models
#
# OUT receives the models (PyTorch names; `pipeline deblur --model OUT/unet32-coded.safetensors`),
# history.csv, report.json and train.log; the end of the generators' logs is printed.
set -euo pipefail
cd "$(dirname "$0")/../.."
G=${1:?GPU_DIR}
OUT=${2:?OUT}
SECS=${3:-470}
if [ -n "${BURST:-}" ]; then
  NETS=${4:-burst-unet32:coded,burst-unet32:conventional}
else
  NETS=${4:-unet32:coded,unet32:conventional,unet16:coded,shallow32:coded}
fi
start=$(date +%s)
until=$((start + SECS))
W=${WORK:-/tmp/gpu-work}
mkdir -p "$W" "$OUT"
tar xf "$G/data.tar" -C "$W"
python3 - "$W/photos/train" <<'PY'
import glob, os, sys
from multiprocessing import Pool
from PIL import Image
def png(f):
    Image.open(f).convert("RGB").save(f[:-4] + ".png")
    os.remove(f)
with Pool() as p:
    p.map(png, sorted(glob.glob(f"{sys.argv[1]}/*.jpg")))
PY
nproc=$(nproc)
# All cores but two render; the coded camera gets 4 of every 7, since its blur costs more (28
# against 40 sub-frames/s per process on the H200 machine) and training waits for both.
free=$((nproc > 4 ? nproc - 2 : 2))
procs_coded=$((free * 4 / 7 > 1 ? free * 4 / 7 : 1))
procs_conv=$((free - procs_coded > 1 ? free - procs_coded : 1))
echo "run.sh: $nproc cores, $procs_coded generator processes for the coded camera, $procs_conv for the conventional; $(ls "$W/photos/train" | wc -l) crops, $(ls "$W/objects" | wc -l) cut-outs"

gen() {
  # One process per core (--shard-index / --shard-count split the photographs; each input's
  # randomness comes from the seed and its name, so the split changes nothing in the data).
  local cam=$1 procs=$2 p=0 ns=(9 7 11 13) burst=()
  # Burst shards: N = 9 only (every sample holds N targets; one layout per run).
  [ -n "${BURST:-}" ] && ns=(9) && burst=(--set transforms.blur.burst=true)
  while [ "$(date +%s)" -lt "$until" ]; do
    local n=${ns[$((p % ${#ns[@]}))]} pids=()
    for ((i = 0; i < procs; i++)); do
      RAYON_NUM_THREADS=1 "$G/pipeline" run pipelines/train-data.toml -o "$W/shards/$cam/p$p" --progress never \
        --shard-index $i --shard-count $procs --set seed=$((${SEED0:-1000} + p)) --set transforms.blur.window=$n \
        --set sources.stills.frames=$((8 * n)) --set transforms.patches.per_window=6 \
        --set transforms.blur.camera.type=$cam --set sinks.shards.prefix=p$p "${burst[@]}" \
        --set "sources.stills.paths=[\"$W/photos/train\"]" --set "sources.stills.motion.object_paths=[\"$W/objects\"]" &
      pids+=($!)
    done
    for pid in "${pids[@]}"; do wait "$pid" || { echo "run.sh: pass $p ($cam) failed"; return; }; done
    p=$((p + 1))
  done
}
gen phase_coded "$procs_coded" >"$W/gen-coded.log" 2>&1 &
g1=$!
gen conventional "$procs_conv" >"$W/gen-conventional.log" 2>&1 &
g2=$!
trap 'kill $g1 $g2 2>/dev/null; pkill -f "$G/pipeline run" 2>/dev/null; tail -n 4 "$W/gen-coded.log" "$W/gen-conventional.log"' EXIT

init=()
[ -d "$G/init" ] && init=(--init "$G/init")  # NAME.safetensors: the nets that do not start from scratch
# The schedule ends 45 s before the deadline: BatchNorm statistics, saving and validation follow.
PYTHONUNBUFFERED=1 python3 docs/gpu/train.py --coded "$W/shards/phase_coded" --conventional "$W/shards/conventional" \
  --out "$OUT" --until $((until - 45)) --nets "$NETS" "${init[@]}" ${TRAIN_ARGS:-}
echo "run.sh: shards written: coded $(find "$W/shards/phase_coded" -name '*.tar' | wc -l), conventional $(find "$W/shards/conventional" -name '*.tar' | wc -l); $(($(date +%s) - start)) s"
