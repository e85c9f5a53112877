#!/usr/bin/env bash
# The release recipe of the shipped checkpoints trained on a GPU machine (one call, ~9 minutes on
# one H100/H200 with 16 CPU cores): simulate mixed training drives, train the small R1 / R2, the
# small near-truth R0 (the hybrid's refining network) and the paper R1 networks on them with the
# depth path real data use (lidar-densified), fit their
# exported covariance on validation drives, evaluate on held-out drives, and pack the results.
#
#   OUT=/path/to/results bash learned/recipes/train_release.sh
#
# Environment (defaults are the release run):
#   DEVICE=cuda|cpu  VEHICLES=14 FRAMES=60 (per preset; training)  TRAIN_S=300 (wall budget of the
#   training stage, seconds; each run keeps its last finished epoch)  SIM_WORKERS=4 (per preset)
#   LOADER_WORKERS=3  RANDOMISE="..." (extra `simulate --set` overrides: the domain randomisation)
#   PAPER=1 (also train the paper preset)  PY=python3
# Seeds: training drives 7001-7004, validation 7101-7103, test 9201-9203 (the test seeds of
# docs/benchmarks.md; never trained or fitted on).
set -uo pipefail
: "${OUT:?set OUT to the results folder}"
PY=${PY:-python3}
DEVICE=${DEVICE:-cuda}
VEHICLES=${VEHICLES:-14}
FRAMES=${FRAMES:-60}
TRAIN_S=${TRAIN_S:-300}
SIM_WORKERS=${SIM_WORKERS:-4}
LOADER_WORKERS=${LOADER_WORKERS:-3}
RANDOMISE=${RANDOMISE:-}
PAPER=${PAPER:-1}
EPOCHS=${EPOCHS:-60}
HELD_VEHICLES=${HELD_VEHICLES:-2}
HELD_FRAMES=${HELD_FRAMES:-40}
SAMPLES=${SAMPLES:-1600}
W=${WORK:-/tmp/release}
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1
hc="$PY -m hybrid_calib.cli"
mkdir -p "$W" "$OUT"
t0=$(date +%s)
stamp() { echo "[$(( $(date +%s) - t0 )) s] $*"; }
(nvidia-smi -L 2>/dev/null || true; nproc) | tee "$OUT/machine.txt"

stamp "simulate training / validation / test drives"
i=0
for sc in urban highway rain straight; do
  i=$((i + 1))
  $hc simulate --scenario $sc --vehicles "$VEHICLES" --frames "$FRAMES" --seed $((7000 + i)) --workers "$SIM_WORKERS" \
    --set image_scale=0.25 $RANDOMISE --out "$W/train-$sc" > "$W/sim-train-$sc.log" 2>&1 &
done
wait
i=0
for sc in urban highway rain; do
  i=$((i + 1))
  $hc simulate --scenario $sc --vehicles "$HELD_VEHICLES" --frames "$HELD_FRAMES" --seed $((7100 + i)) --workers 2 \
    --set image_scale=0.25 $RANDOMISE --out "$W/val-$sc" > "$W/sim-val-$sc.log" 2>&1 &
  $hc simulate --scenario $sc --vehicles "$HELD_VEHICLES" --frames "$HELD_FRAMES" --seed $((9200 + i)) --workers 2 \
    --set image_scale=0.25 --out "$W/test-$sc" > "$W/sim-test-$sc.log" 2>&1 &
done
wait
tail -n 1 "$W"/sim-*.log
stamp "simulated"

common="--depth lidar-densified --set device=$DEVICE num_workers=$LOADER_WORKERS depth_cache=$W/depth-cache threads=2"
train_data="$W/train-urban $W/train-highway $W/train-rain $W/train-straight"
stamp "train (budget $TRAIN_S s each, in parallel)"
timeout "$TRAIN_S" $hc train --data $train_data --preset small --range R1 --init learned/checkpoints/small-sim-r1.json \
  --epochs "$EPOCHS" $common batch_size=16 lr=2e-4 lr_halve_every=15 samples_per_epoch="$SAMPLES" val_samples=128 \
  --out "$W/small-r1" --no-progress > "$W/train-small-r1.log" 2>&1 &
timeout "$TRAIN_S" $hc train --data $train_data --preset small --range R2 --init learned/checkpoints/small-sim-r2.json \
  --epochs "$EPOCHS" $common batch_size=16 lr=2e-4 lr_halve_every=15 samples_per_epoch="$SAMPLES" val_samples=128 \
  --out "$W/small-r2" --no-progress > "$W/train-small-r2.log" 2>&1 &
timeout "$TRAIN_S" $hc train --data $train_data --preset small --range R0 --init learned/checkpoints/small-sim-r1.json \
  --epochs "$EPOCHS" $common batch_size=16 lr=2e-4 lr_halve_every=15 samples_per_epoch="$SAMPLES" val_samples=128 \
  --out "$W/small-r0" --no-progress > "$W/train-small-r0.log" 2>&1 &
if [ "$PAPER" = 1 ]; then
  timeout "$TRAIN_S" $hc train --data $train_data --preset paper --range R1 --epochs "$EPOCHS" $common \
    batch_size=16 lr=3e-4 lr_halve_every=15 samples_per_epoch="$SAMPLES" val_samples=128 \
    --out "$W/paper-r1" --no-progress > "$W/train-paper-r1.log" 2>&1 &
fi
wait
for r in small-r0 small-r1 small-r2 paper-r1; do [ -f "$W/$r/epochs.csv" ] && { echo "== $r"; tail -n 3 "$W/$r/epochs.csv"; }; done
stamp "trained"

val_data="$W/val-urban $W/val-highway $W/val-rain"
test_data="$W/test-urban $W/test-highway $W/test-rain"
pack() {  # run name, range, output stem
  local run=$1 range=$2 stem=$3 last
  last=$(ls "$W/$run/checkpoints"/ckpt-*.json 2>/dev/null | sort | tail -n 1)
  [ -n "$last" ] || { echo "no checkpoint for $run"; return; }
  mkdir -p "$W/ship"
  cp "$last" "$W/ship/$stem.json"
  cp "${last%.json}.safetensors" "$W/ship/$stem.safetensors"
  $PY - "$W/ship/$stem.json" <<'PYEOF'
import json, sys
p = sys.argv[1]
m = json.load(open(p))
m["files"] = {"weights": p.rsplit("/", 1)[1].replace(".json", ".safetensors")}
json.dump(m, open(p, "w"), indent=2)
PYEOF
  timeout 90 $hc evaluate --data $val_data --split all --range "$range" --checkpoint "$W/ship/$stem.json" --fit-uncertainty \
    --depth lidar-densified --set device="$DEVICE" --out "$W/fit-$stem" --no-progress > "$W/fit-$stem.log" 2>&1
  timeout 60 $PY benchmarks/correspondence_quality.py --eval "$W/fit-$stem" --data $val_data \
    --fit-into "$W/ship/$stem.json" > "$W/sigma-$stem.log" 2>&1
  timeout 90 $hc evaluate --data $test_data --split all --range "$range" --checkpoint "$W/ship/$stem.json" \
    --depth lidar-densified --set device="$DEVICE" --out "$W/eval-$stem" --no-progress > "$W/eval-$stem.log" 2>&1
  tail -n 25 "$W/eval-$stem.log"
}
stamp "fit and evaluate"
pack small-r1 R1 small-sim-r1 &
pack small-r2 R2 small-sim-r2 &
pack small-r0 R0 small-sim-r0 &
[ "$PAPER" = 1 ] && pack paper-r1 R1 paper-sim-r1 &
wait
stamp "evaluated"

# pack: small weights as they are; the paper weights in float16 (<= 25 MB) split in two (<= 16 MB a file)
cd "$W/ship" && cp small-sim-r0.safetensors small-sim-r1.safetensors small-sim-r2.safetensors "$OUT/" 2>/dev/null
if [ -f paper-sim-r1.safetensors ]; then
  $PY -c "
from safetensors.torch import load_file, save_file
s = load_file('paper-sim-r1.safetensors'); save_file({k: v.half() if v.is_floating_point() else v for k, v in s.items()}, 'paper16.safetensors')"
  split -b 15M paper16.safetensors "$OUT/paper-sim-r1.safetensors.part-"
fi
cp "$OUT/machine.txt" "$W/" && rm "$OUT/machine.txt"
cd "$W" && tar czf "$OUT/logs.tgz" ./machine.txt ./ship/*.json ./*.log ./*/epochs.csv ./eval-*/results.* ./fit-*/results.* 2>/dev/null
ls -la "$OUT"
stamp "done"
