#!/usr/bin/env bash
# Reproduces the committed models in exported/: data from exploration episodes on the KTH train maps (never
# the eval maps) with the default sensing (256 secondary rays, 20-degree sector margin), the Pix2Pix filter, the
# Pix2Pix-filtered LaMa data, the LaMa-BP ensemble, calibration, export with parity.
#
#   bash scripts/train_models.sh                 # CPU, 2 cores: the reference (hours; see docs/models.md)
#   DEVICE=cuda JOBS=16 bash scripts/train_models.sh   # the same commands on a GPU machine
#
# Every step resumes: datasets already written are kept, training continues from the last epoch's checkpoint.
#
# LaMa-LOS sees no SPAD data (its tiles are the observed map only, from trajectories planned on the observed
# map), so the committed members (LOS_FROM, default exported/checkpoints) are kept and their calibration with
# them; LOS_FROM= (empty) trains them again (16 epochs from a random start, as they were made).
# The LaMa-BP members start from the LaMa-LOS members (the evidence channel's stem weights start at zero, so each
# BP member first predicts what its LOS member does) and are fine-tuned on the Pix2Pix-filtered data: BP_EPOCHS
# epochs, cosine learning rate from 5e-4. Every committed model comes from these commands.
# WORK (default runs/training) holds the datasets and runs; OUT (default exported/) receives the models.
set -euo pipefail

DEVICE=${DEVICE:-cpu}
JOBS=${JOBS:-2}
THREADS=${THREADS:-2}
WORK=${WORK:-runs/training}
OUT=${OUT:-exported}
SUPEREX=${SUPEREX:-superex}
QUIET=${QUIET:-}
P2P_EPOCHS=${P2P_EPOCHS:-16}
BP_EPOCHS=${BP_EPOCHS:-10}
LOS_FROM=${LOS_FROM-exported/checkpoints}
STOP_AFTER=${STOP_AFTER:-}   # "calibration": leave the final export (into OUT) to a later call
# SMOKE=1: the whole chain on 2 train maps, 2 batches an epoch and 2 calibration maps (minutes; checks the chain)
DATA_LIMIT=() TRAIN_LIMIT=() CAL_LIMIT=()
if [ -n "${SMOKE:-}" ]; then
  DATA_LIMIT=(--maps 0510025536_Layout1_PLAN4 0510032192_A_40_1_103)
  TRAIN_LIMIT=(--max-batches 2) CAL_LIMIT=(--max-maps 2 --steps 60) P2P_EPOCHS=1 BP_EPOCHS=1
fi

# The data and calibration steps run JOBS processes: one numba thread each (numba's default, a thread per core in
# every process, oversubscribes the machine: 16 processes x 16 threads had not written the LaMa data after 290 s
# on a 16-core machine, one thread each wrote it in 113 s).
export NUMBA_NUM_THREADS=${NUMBA_NUM_THREADS:-1}

mkdir -p "$WORK"
step() { echo "== $(date +%H:%M:%S) $*"; }

if [ ! -f "$WORK/pix2pix_data/index.json" ]; then
  step "Pix2Pix data"
  $SUPEREX train data pix2pix --out "$WORK/pix2pix_data" --episodes-per-map 4 --steps 300 --sample-every 16 \
    --jobs "$JOBS" "${DATA_LIMIT[@]}" $QUIET
fi

step "Pix2Pix training"
$SUPEREX train pix2pix --data "$WORK/pix2pix_data" --out "$WORK/pix2pix" --epochs "$P2P_EPOCHS" --batch-size 16 \
  --lr 1e-3 --lr-schedule cosine --wall-weight 12 --l1-weight 1 --bce-weight 1 --dice-weight 1 \
  --adversarial-weight 0.01 --input-encoding log --device "$DEVICE" --threads "$THREADS" "${TRAIN_LIMIT[@]}" $QUIET

step "Pix2Pix export (filters the LaMa data's evidence)"
$SUPEREX export --pix2pix "$WORK/pix2pix" --out "$WORK/pix2pix_export"

if [ ! -f "$WORK/lama_data/lama_bp/index.json" ]; then
  step "LaMa data"
  rm -rf "$WORK/lama_data"
  $SUPEREX train data lama --out "$WORK/lama_data" --pix2pix-model "$WORK/pix2pix_export/pix2pix.onnx" \
    --episodes-per-map 2 --steps 300 --sample-every 12 --tile 128 --tiles-per-sample 2 --jobs "$JOBS" "${DATA_LIMIT[@]}" $QUIET
fi

if [ -n "$LOS_FROM" ]; then
  LOS_MEMBERS=("$LOS_FROM"/lama_los_{0,1,2}.pt)
  LOS_INIT="$LOS_FROM/lama_los_{member}.pt"
  CALIBRATE=(--kinds bp --keep-from "${LOS_FROM%/checkpoints}/calibration.json")
else
  step "LaMa (los) ensemble training"
  $SUPEREX train lama --kind los --data "$WORK/lama_data/lama_los" --out "$WORK/lama_los" --members 3 \
    --epochs 16 --batch-size 16 --device "$DEVICE" --threads "$THREADS" "${TRAIN_LIMIT[@]}" $QUIET
  LOS_MEMBERS=("$WORK/lama_los")
  LOS_INIT="$WORK/lama_los/member_{member}/checkpoint.pt"
  CALIBRATE=(--kinds bp los)
fi

step "LaMa (bp) ensemble: fine-tuned from the LOS members (one process per member)"
pids=()
for member in 0 1 2; do
  $SUPEREX train lama --kind bp --data "$WORK/lama_data/lama_bp" --out "$WORK/lama_bp" --members 3 \
    --only-member "$member" --init-from "$LOS_INIT" --epochs "$BP_EPOCHS" --lr 5e-4 --lr-schedule cosine \
    --batch-size 16 --device "$DEVICE" --threads 1 "${TRAIN_LIMIT[@]}" --quiet > "$WORK/lama_bp_member_$member.log" 2>&1 &
  pids+=($!)
done
for pid in "${pids[@]}"; do wait "$pid"; done
tail -n 3 "$WORK"/lama_bp_member_*.log

step "Calibration (Platt scaling on episodes of the training buildings)"
$SUPEREX export --pix2pix "$WORK/pix2pix" --lama-bp "$WORK/lama_bp" --lama-los "${LOS_MEMBERS[@]}" \
  --out "$WORK/uncalibrated"
$SUPEREX train calibrate --models "$WORK/uncalibrated" --out "$WORK/calibration.json" --jobs "$JOBS" \
  "${CALIBRATE[@]}" "${CAL_LIMIT[@]}"
[ "$STOP_AFTER" = calibration ] && { step "stopped after calibration"; exit 0; }

step "Export"
$SUPEREX export --pix2pix "$WORK/pix2pix" --lama-bp "$WORK/lama_bp" --lama-los "${LOS_MEMBERS[@]}" \
  --calibration "$WORK/calibration.json" --out "$OUT"
step "done"
