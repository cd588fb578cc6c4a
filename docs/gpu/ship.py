"""Writes a shipped model folder's report.json, history.csv and curves.png from the rounds of
docs/gpu/run.sh that trained it (the weights themselves: `pipeline export ROUND/NAME.safetensors
--format burn --half -o models/NAME/model.safetensors`).

    python3 docs/gpu/ship.py NAME OUT_DIR ROUND_DIR [ROUND_DIR...]     # curves need matplotlib
    INIT="models/shallow32-coded at commit 9c67bda" python3 docs/gpu/ship.py ...   # what round 1 started from
"""

import csv
import json
import os
import sys

name, out, rounds = sys.argv[1], sys.argv[2], sys.argv[3:]
os.makedirs(out, exist_ok=True)
kind = name.split("-")[0]
arch = f"unet-{kind[4:]}" if kind.startswith("unet") else f"shallow-{kind[7:]}"  # as `pipeline` names it
report = {"model": name, "arch": arch, "trained_by": "docs/gpu/train.py via docs/gpu/run.sh (PyTorch, one NVIDIA H200)",
          "init": os.environ.get("INIT", "from scratch (the last layer zeroed: the identity)"), "rounds": []}
rows, offset = [], 0
for i, d in enumerate(rounds):
    r = json.load(open(os.path.join(d, "report.json")))
    report["rounds"].append({"round": i + 1, "steps": r["steps"], "batch": r["batch"], "patches": r["patches_per_model"],
                             "distinct_samples": r["samples"], "seconds": r["seconds"], "held_out": r["held_out"],
                             "validation": r["val"].get(name)})
    with open(os.path.join(d, "history.csv")) as f:
        for h in csv.DictReader(f):
            if h.get(name):
                rows.append({"round": i + 1, "step": offset + int(h["step"]), "patches": (offset + int(h["step"])) * r["batch"],
                             "lr": h["lr"], "loss": h[name], "distinct_samples": h["samples"]})
    offset += r["steps"]
report["patches"] = sum(r["patches"] for r in report["rounds"])
json.dump(report, open(os.path.join(out, "report.json"), "w"), indent=1)
with open(os.path.join(out, "history.csv"), "w", newline="") as f:
    w = csv.DictWriter(f, fieldnames=["round", "step", "patches", "lr", "loss", "distinct_samples"])
    w.writeheader()
    w.writerows(rows)
try:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
except ImportError:
    print("no matplotlib: curves.png not drawn", file=sys.stderr)
else:
    fig, ax = plt.subplots(figsize=(6, 3.2), dpi=100)
    for i in range(len(rounds)):
        rr = [r for r in rows if r["round"] == i + 1 and int(r["step"]) > 0]
        ax.plot([r["patches"] / 1e3 for r in rr], [float(r["loss"]) for r in rr], label=f"round {i + 1}")
    ax.set_yscale("log")
    ax.set_xlabel("thousand patches")
    ax.set_ylabel("training loss (Huber, 10 s means)")
    ax.set_title(name)
    ax.legend()
    fig.tight_layout()
    fig.savefig(os.path.join(out, "curves.png"))
print(f"{name}: {report['patches']} patches in {len(rounds)} rounds -> {out}")
