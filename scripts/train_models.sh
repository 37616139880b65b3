#!/usr/bin/env bash
# Reproduces the committed models in exported/: data from exploration episodes on the KTH train maps (never
# the eval maps), the Pix2Pix filter, the Pix2Pix-filtered LaMa data, both LaMa ensembles, export with parity.
#
#   bash scripts/train_models.sh                 # CPU, 2 cores: the reference (hours; see docs/models.md)
#   DEVICE=cuda JOBS=15 bash scripts/train_models.sh   # the same commands on a GPU machine
#
# Every step resumes: datasets already written are kept, training continues from the last epoch's checkpoint.
#
# The LaMa-BP members start from the LaMa-LOS members (the evidence channel's stem weights start at zero, so each
# BP member first predicts what its LOS member does) and are fine-tuned on the Pix2Pix-filtered data: 5 epochs,
# cosine learning rate from 5e-4. Every committed model comes from these commands.
# WORK (default runs/training) holds the datasets and runs; OUT (default exported/) receives the models.
set -euo pipefail

DEVICE=${DEVICE:-cpu}
JOBS=${JOBS:-2}
THREADS=${THREADS:-2}
WORK=${WORK:-runs/training}
OUT=${OUT:-exported}
SUPEREX=${SUPEREX:-superex}
QUIET=${QUIET:-}

mkdir -p "$WORK"
step() { echo "== $(date +%H:%M:%S) $*"; }

if [ ! -f "$WORK/pix2pix_data/index.json" ]; then
  step "Pix2Pix data"
  $SUPEREX train data pix2pix --out "$WORK/pix2pix_data" --episodes-per-map 4 --steps 300 --sample-every 16 \
    --jobs "$JOBS" $QUIET
fi

step "Pix2Pix training"
$SUPEREX train pix2pix --data "$WORK/pix2pix_data" --out "$WORK/pix2pix" --epochs 8 --batch-size 16 --lr 1e-3 \
  --lr-schedule cosine --wall-weight 12 --l1-weight 1 --bce-weight 1 --dice-weight 1 --adversarial-weight 0.01 \
  --input-encoding log --device "$DEVICE" --threads "$THREADS" $QUIET

step "Pix2Pix export (filters the LaMa data's evidence)"
$SUPEREX export --pix2pix "$WORK/pix2pix" --out "$WORK/pix2pix_export"

if [ ! -f "$WORK/lama_data/lama_bp/index.json" ]; then
  step "LaMa data"
  rm -rf "$WORK/lama_data"
  $SUPEREX train data lama --out "$WORK/lama_data" --pix2pix-model "$WORK/pix2pix_export/pix2pix.onnx" \
    --episodes-per-map 2 --steps 300 --sample-every 12 --tile 128 --tiles-per-sample 2 --jobs "$JOBS" $QUIET
fi

step "LaMa (los) ensemble training"
$SUPEREX train lama --kind los --data "$WORK/lama_data/lama_los" --out "$WORK/lama_los" --members 3 \
  --epochs 16 --batch-size 16 --device "$DEVICE" --threads "$THREADS" $QUIET

step "LaMa (bp) ensemble: fine-tuned from the LOS members"
$SUPEREX train lama --kind bp --data "$WORK/lama_data/lama_bp" --out "$WORK/lama_bp" --members 3 \
  --init-from "$WORK/lama_los/member_{member}/checkpoint.pt" --epochs 5 --lr 5e-4 --lr-schedule cosine \
  --batch-size 16 --device "$DEVICE" --threads "$THREADS" $QUIET

step "Calibration (Platt scaling on episodes of the training buildings)"
$SUPEREX export --pix2pix "$WORK/pix2pix" --lama-bp "$WORK/lama_bp" --lama-los "$WORK/lama_los" \
  --out "$WORK/uncalibrated"
$SUPEREX train calibrate --models "$WORK/uncalibrated" --out "$WORK/calibration.json" --jobs "$JOBS"

step "Export"
$SUPEREX export --pix2pix "$WORK/pix2pix" --lama-bp "$WORK/lama_bp" --lama-los "$WORK/lama_los" \
  --calibration "$WORK/calibration.json" --out "$OUT"
step "done"
