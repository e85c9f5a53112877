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
#   training stage, seconds; each run keeps its last finished epoch)  POST_S=400 (wall budget of the
#   fits and evaluations; the weights are in OUT before they start)  DEADLINE_S (optional: the whole
#   recipe's wall budget; training is cut to fit it)  SIM_WORKERS=4 (per preset)
#   LOADER_WORKERS=3  RANDOMISE="..." (extra `simulate --set` overrides: the domain randomisation)
#   SMALL=1 (train the small R1 / R2 / R0)  PAPER=1 (also train the paper preset)
#   PAPER_RANGES="R1" (the paper networks to train)  PAPER_INIT="" (a checkpoint to start every paper
#   network from; "" = from scratch)  PAPER_LR=3e-4  PAPER_HALVE=15 (epochs per halving)
#   BASELINE=0 (1: also evaluate the checkpoints shipped now on the same test drives, same machine)
#   OOD=0 (1: fit each new checkpoint's out-of-domain score, benchmarks/ood_fit.py, on its own
#   simulated drives, seeds 9311-9313 fit and 9411-9413 measure)  PY=python3
# Seeds: training drives 7001-7004, validation 7101-7103, test 9201-9203 (the test seeds of
# docs/benchmarks.md; never trained or fitted on).
set -uo pipefail
: "${OUT:?set OUT to the results folder}"
PY=${PY:-python3}
DEVICE=${DEVICE:-cuda}
VEHICLES=${VEHICLES:-14}
FRAMES=${FRAMES:-60}
TRAIN_S=${TRAIN_S:-300}
POST_S=${POST_S:-400}
SIM_WORKERS=${SIM_WORKERS:-4}
LOADER_WORKERS=${LOADER_WORKERS:-3}
RANDOMISE=${RANDOMISE:-}
PAPER=${PAPER:-1}
SMALL=${SMALL:-1}
PAPER_RANGES=${PAPER_RANGES:-R1}
[ "$PAPER" = 1 ] || PAPER_RANGES=""
PAPER_INIT=${PAPER_INIT:-}
PAPER_LR=${PAPER_LR:-3e-4}
PAPER_HALVE=${PAPER_HALVE:-15}
BASELINE=${BASELINE:-0}
OOD=${OOD:-0}
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
if [ "$OOD" = 1 ]; then  # the out-of-domain score's own drives (benchmarks/ood_fit.py; docs/benchmarks.md)
  for s in urban:9311 highway:9312 rain:9313 urban:9411 highway:9412 rain:9413; do
    $hc simulate --scenario ${s%%:*} --vehicles 1 --frames "${OOD_FRAMES:-40}" --seed ${s##*:} --set image_scale=0.25 \
      --out "$W/ood-${s%%:*}-${s##*:}" > "$W/sim-ood-${s##*:}.log" 2>&1 &
  done
fi
wait
tail -n 1 "$W"/sim-*.log
stamp "simulated"

common="--depth lidar-densified --set device=$DEVICE num_workers=$LOADER_WORKERS depth_cache=$W/depth-cache threads=2"
train_data="$W/train-urban $W/train-highway $W/train-rain $W/train-straight"
if [ -n "${DEADLINE_S:-}" ]; then  # the whole recipe within DEADLINE_S: training gets what the rest leaves
  left=$(( DEADLINE_S - ($(date +%s) - t0) - POST_S - 40 ))
  [ "$left" -lt "$TRAIN_S" ] && TRAIN_S=$left
fi
stamp "train (budget $TRAIN_S s each, in parallel)"
if [ "$SMALL" = 1 ]; then
  for r in R1 R2 R0; do
    init=learned/checkpoints/small-sim-r1.json; [ $r = R2 ] && init=learned/checkpoints/small-sim-r2.json
    timeout "$TRAIN_S" $hc train --data $train_data --preset small --range $r --init $init \
      --epochs "$EPOCHS" $common batch_size=16 lr=2e-4 lr_halve_every=15 samples_per_epoch="$SAMPLES" val_samples=128 \
      --out "$W/small-${r,,}" --no-progress > "$W/train-small-${r,,}.log" 2>&1 &
  done
fi
for r in $PAPER_RANGES; do
  timeout "$TRAIN_S" $hc train --data $train_data --preset paper --range $r ${PAPER_INIT:+--init "$PAPER_INIT"} \
    --epochs "$EPOCHS" $common batch_size=16 lr="$PAPER_LR" lr_halve_every="$PAPER_HALVE" samples_per_epoch="$SAMPLES" \
    val_samples=128 --out "$W/paper-${r,,}" --no-progress > "$W/train-paper-${r,,}.log" 2>&1 &
done
wait
for r in small-r0 small-r1 small-r2 paper-r1 paper-r2; do [ -f "$W/$r/epochs.csv" ] && { echo "== $r"; tail -n 3 "$W/$r/epochs.csv"; }; done
stamp "trained"

val_data="$W/val-urban $W/val-highway $W/val-rain"
test_data="$W/test-urban $W/test-highway $W/test-rain"
ship() {  # run name, output stem: the last finished epoch into $W/ship, the weights into $OUT at once
  local run=$1 stem=$2 last
  last=$(ls "$W/$run/checkpoints"/ckpt-*.json 2>/dev/null | sort | tail -n 1)
  [ -n "$last" ] || { echo "no checkpoint for $run"; return; }
  mkdir -p "$W/ship"
  cp "$last" "$W/ship/$stem.json"
  cp "${last%.json}.safetensors" "$W/ship/$stem.safetensors"
  # files keeps the weights' name only: the fits below run on these float32 weights, the paper's ship in float16;
  # put files.weights_sha256 (learned.checkpoint.weights_sha256 of the file as shipped) in the JSON shipped beside it
  $PY - "$W/ship/$stem.json" <<'PYEOF'
import json, sys
p = sys.argv[1]
m = json.load(open(p))
m["files"] = {"weights": p.rsplit("/", 1)[1].replace(".json", ".safetensors")}
json.dump(m, open(p, "w"), indent=2)
PYEOF
  # small weights as they are; paper weights in float16 (<= 25 MB) split in two (<= 16 MB a file)
  case $stem in
    small-*) cp "$W/ship/$stem.safetensors" "$OUT/" ;;
    paper-*) $PY -c "
import sys
from safetensors.torch import load_file, save_file
s = load_file(sys.argv[1]); save_file({k: v.half() if v.is_floating_point() else v for k, v in s.items()}, sys.argv[2])" \
               "$W/ship/$stem.safetensors" "$W/$stem-16.safetensors"
             split -b 15M "$W/$stem-16.safetensors" "$OUT/$stem.safetensors.part-" ;;
  esac
}
cap() {  # a step's timeout: $1 seconds, or what is left of the POST_S budget
  local left=$(( post_end - $(date +%s) ))
  if [ "$left" -lt "$1" ]; then echo $(( left > 1 ? left : 1 )); else echo "$1"; fi
}
fit_eval() {  # range, output stem: covariance and pixel noise fitted on validation drives, then the test drives
  local range=$1 stem=$2
  [ -f "$W/ship/$stem.json" ] || return
  local ev="--depth lidar-densified --set device=$DEVICE depth_cache=$W/depth-cache-eval"
  timeout "$(cap 90)" $hc evaluate --data $val_data --split all --range "$range" --checkpoint "$W/ship/$stem.json" --fit-uncertainty \
    $ev --out "$W/fit-$stem" --no-progress > "$W/fit-$stem.log" 2>&1
  timeout "$(cap 60)" $PY benchmarks/correspondence_quality.py --eval "$W/fit-$stem" --data $val_data \
    --fit-into "$W/ship/$stem.json" > "$W/sigma-$stem.log" 2>&1
  timeout "$(cap 90)" $hc evaluate --data $test_data --split all --range "$range" --checkpoint "$W/ship/$stem.json" \
    $ev --out "$W/eval-$stem" --no-progress > "$W/eval-$stem.log" 2>&1
  tail -n 25 "$W/eval-$stem.log"
  if [ "$BASELINE" = 1 ] && [ -f "learned/checkpoints/$stem.json" ]; then
    timeout "$(cap 90)" $hc evaluate --data $test_data --split all --range "$range" --checkpoint "learned/checkpoints/$stem.json" \
      $ev --out "$W/base-$stem" --no-progress > "$W/base-$stem.log" 2>&1
    echo "== shipped $stem on the same test drives"; tail -n 25 "$W/base-$stem.log"
  fi
  if [ "$OOD" = 1 ]; then
    timeout "$(cap 150)" $PY benchmarks/ood_fit.py --checkpoint "$W/ship/$stem.json" --device "$DEVICE" --threads 2 \
      --data "$W/ood-urban-9311" "$W/ood-highway-9312" "$W/ood-rain-9313" \
      --heldout "$W/ood-urban-9411" "$W/ood-highway-9412" "$W/ood-rain-9413" \
      --out "$W/ood-$stem" --fit-into > "$W/ood-$stem.log" 2>&1
    echo "== out-of-domain score of $stem"; grep "chosen" "$W/ood-$stem.log"
  fi
}
runs=""
[ "$SMALL" = 1 ] && runs="small-r1:R1:small-sim-r1 small-r2:R2:small-sim-r2 small-r0:R0:small-sim-r0"
for r in $PAPER_RANGES; do runs="$runs paper-${r,,}:$r:paper-sim-${r,,}"; done
for x in $runs; do IFS=: read -r run range stem <<< "$x"; ship "$run" "$stem"; done
stamp "shipped the weights; fit and evaluate (at most $POST_S s)"
post_end=$(( $(date +%s) + POST_S ))
for x in $runs; do IFS=: read -r run range stem <<< "$x"; fit_eval "$range" "$stem" & done
wait
stamp "evaluated"

cp "$OUT/machine.txt" "$W/" && rm "$OUT/machine.txt"
cd "$W" && tar czf "$OUT/logs.tgz" ./machine.txt ./ship/*.json ./*.log ./*/epochs.csv ./eval-*/results.* ./fit-*/results.* \
  ./base-*/results.* ./ood-*/ood.json 2>/dev/null
ls -la "$OUT"
stamp "done"
