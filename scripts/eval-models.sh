#!/usr/bin/env bash
# Scores a coded and a conventional model on the held-out test clips of scripts/training-data.sh,
# one motion at a time (shake, objects, still, pan, rotate, zoom), and prints the summary tables
# of docs/eval.md: per motion and camera, N = 7 to 13 averaged over sigma 0 to 3, input, model,
# gain, the Wiener bound told the true kernel (where the motion has one), and the coded model's
# output minus the conventional model's.
#
#   bash scripts/eval-models.sh models/unet16-coded models/unet16-conventional ../ev/shipped
#   KINDS="shake still" DATA=../data bash scripts/eval-models.sh CODED CONV OUT
#
# Each eval runs on one thread (RAYON_NUM_THREADS=1) beside whatever else runs; an existing
# OUT/<kind>-<camera>/eval.json is kept, so a stopped run goes on where it stopped.
set -euo pipefail
cd "$(dirname "$0")/.."
CODED=${1:?coded model}
CONV=${2:?conventional model}
OUT=${3:?output folder}
DATA=${DATA:-../data}
KINDS=${KINDS:-shake objects still pan rotate zoom}
PIPELINE=${PIPELINE:-target/release/pipeline}
SETS=(--set eval.crop=192 --set eval.windows_per_video=2 --progress never)
mkdir -p "$OUT"
for kind in $KINDS; do
  c="$OUT/$kind-phase_coded"; v="$OUT/$kind-conventional"
  [ -f "$c/eval.json" ] || RAYON_NUM_THREADS=${THREADS:-1} "$PIPELINE" eval "$DATA/test/$kind" -o "$c" --model "$CODED" "${SETS[@]}" >"$c.log" 2>&1
  [ -f "$v/eval.json" ] || RAYON_NUM_THREADS=${THREADS:-1} "$PIPELINE" eval "$DATA/test/$kind" -o "$v" --model "$CONV" --camera conventional \
    --versus "$c/eval.json" "${SETS[@]}" >"$v.log" 2>&1
done
python3 - "$OUT" $KINDS <<'PY'
import json, os, sys
out, kinds = sys.argv[1], sys.argv[2:]
def rows(kind, cam):
    """N -> (input, model, bound, excluded sigmas): PSNR RGB means over the sigmas where each is
    finite (a still frame through the conventional camera at sigma 0 is its sharp frame: infinite)."""
    p = f"{out}/{kind}-{cam}/eval.json"
    if not os.path.exists(p):
        return {}
    by_n = {}
    for r in json.load(open(p))["per_sigma"]:
        by_n.setdefault(r["window"], []).append(r)
    res = {}
    for n, rs in by_n.items():
        ok = [r for r in rs if r["blurred"]["psnr_rgb"] is not None and r["deblurred"]["psnr_rgb"] is not None]
        mean = lambda f: sum(f(r) for r in ok) / len(ok)
        bounds = [r["bound"][0]["psnr_rgb"] for r in ok if r.get("bound") and r["bound"][0]["psnr_rgb"] is not None]
        res[n] = (mean(lambda r: r["blurred"]["psnr_rgb"]), mean(lambda r: r["deblurred"]["psnr_rgb"]),
                  sum(bounds) / len(bounds) if len(bounds) == len(ok) else None, [r["sigma"] for r in rs if r not in ok])
    return res
for kind in kinds:
    c, v = rows(kind, "phase_coded"), rows(kind, "conventional")
    print(f"\n#### {kind}\n")
    print("| N | coded: input -> model (gain) | Wiener, true kernel | conventional: input -> model (gain) | Wiener, true kernel | coded output minus conventional output |")
    print("|---|---|---|---|---|---|")
    notes = set()
    for n in sorted(set(c) | set(v)):
        def cell(r):
            if not r:
                return "-", "-"
            i, m, b, skipped = r
            mark = "*" if skipped else ""
            if skipped:
                notes.update(skipped)
            return f"{i:.2f} -> {m:.2f} ({m - i:+.2f}){mark}", (f"{b:.2f} ({b - i:+.2f})" if b is not None else "-")
        (cc, cb), (vc, vb) = cell(c.get(n)), cell(v.get(n))
        diff = f"{c[n][1] - v[n][1]:+.2f}" if n in c and n in v else "-"
        print(f"| {n} | {cc} | {cb} | {vc} | {vb} | {diff} |")
    if notes:
        print(f"\n\\* mean over the other sigmas: at sigma {sorted(notes)} the input is the sharp frame itself (PSNR infinite).")
PY
