#!/bin/bash
# Checks `imuflow train --device cuda` on a machine with a CUDA GPU: the same seeded run (PIP 64x2,
# two epochs, no dropout) on the CPU and on the GPU, whose losses must agree, then PIP at the
# paper's size (256x2) timed on both (stages/kinematics/README.md, "Training on a GPU").
#
#   scripts/check-cuda.sh BINARY BVH_DIR OUT_DIR
#
# BINARY: an imuflow built with `--features cuda`; BVH_DIR: some clips (200 random Bandai clips were
# used); OUT_DIR: where the logs and both loss.csv go. DEVICES=cpu checks the script without a GPU;
# BIG_MIN limits each timed run (minutes, default 1).
set -o pipefail
if [ $# -ne 3 ]; then echo "usage: $0 BINARY BVH_DIR OUT_DIR" >&2; exit 2; fi
BIN=$1; BVH=$2; OUT=$3; W=$(mktemp -d); mkdir -p "$OUT"; trap 'rm -rf $W' EXIT
nproc; nvidia-smi --query-gpu=name --format=csv,noheader 2>/dev/null
$BIN dataset build --bvh-dir "$BVH" --out $W/ds > $W/build.log 2>&1 || { tail -20 $W/build.log; exit 1; }
tail -3 $W/build.log
for d in ${DEVICES:-cpu cuda}; do
  RAYON_NUM_THREADS=2 $BIN train --method pip --data $W/ds --out $W/small-$d.st --checkpoint-dir $W/ck-small-$d --hidden 64 --epochs 2 --dropout 0 --seed 3 --max-train-frames 150000 --no-progress --device $d 2>&1 | grep -v "train shard" | tee "$OUT"/small-$d.log
  cp $W/ck-small-$d/loss.csv "$OUT"/small-$d.csv
done
for d in ${DEVICES:-cpu cuda}; do
  RAYON_NUM_THREADS=2 $BIN train --method pip --data $W/ds --out $W/big-$d.st --checkpoint-dir $W/ck-big-$d --hidden 256 --layers 2 --epochs 1 --max-minutes ${BIG_MIN:-1} --seed 3 --no-progress --device $d 2>&1 | grep -v "train shard" | tee "$OUT"/big-$d.log
done
python3 - "$OUT" <<'P'
import sys, csv
out = sys.argv[1]
try:
    rows = {d: list(csv.DictReader(open(f"{out}/small-{d}.csv"))) for d in ("cpu", "cuda")}
except FileNotFoundError as e:
    print("no comparison:", e); sys.exit(0)
worst = 0.0
for a, b in zip(rows["cpu"], rows["cuda"]):
    for k in a:
        if k.startswith(("train_", "val_")):
            x, y = float(a[k]), float(b[k]); r = abs(x - y) / max(abs(x), 1e-12); worst = max(worst, r)
            print(f"epoch {a['epoch']} {k}: cpu {x:.6g} cuda {y:.6g} rel {r:.2e}")
print(f"largest relative difference cpu vs cuda: {worst:.2e}")
sys.exit(0 if worst < 1e-3 else 1)
P
