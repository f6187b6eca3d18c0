#!/bin/bash
# The workflow's pretrain -> fine-tune -> evaluate chain on a GPU machine (issue #15, item 7), with the default
# params: the 480 source and 960 pretraining scenes, the nominal and D 0.5 m test stores, then
#   1. 5 pretraining epochs with the draws in the training thread and in processes (--draw-workers), timed;
#   2. the default pretraining (20 epochs, 3 replicates), fine-tuned (4 epochs) and scored at both points;
#   3. more pretraining epochs in the time left, fine-tuned and scored.
# Run from the repository root: OUT=dir bash benchmarks/gpu_chain.sh [BUDGET_S, default 540]; RESULT lines in
# $OUT/progress.txt. The environment and the data: benchmarks/gpu_common.sh.
# A dry run on a CPU: OUT=/tmp/o NS=12 NX=8 SIZE=256 DEV=cpu ESPEED=1 EDEF=2 EMIN=2 DW=2 bash benchmarks/gpu_chain.sh 300
# Measured 2026-11-27 on one H100 (16 cores), budget 515 s: scenes 61 s, test stores 27 s, step 1 115 s, the
# default pretraining 202 s (+ 20 s of fields), the nominal's fine-tune 19 s, nominal IoU 0.209 +- 0.009; the
# D 0.5 m fine-tune and step 3 ran out of time (docs/training.md, "GPUs").
set -uo pipefail
BUDGET=${1:-540}
. benchmarks/gpu_common.sh
ESPEED=${ESPEED:-5}; EDEF=${EDEF:-20}; EMIN=${EMIN:-40}; DW=${DW:-$((NC - 2))}
log "cores $NC, draw workers $DW, budget $BUDGET s"
gpu_data || exit 1

pretrain() {  # name epochs replicates draw-workers
  log "pretrain $1: $2 epochs, $3 replicate(s), $4 draw workers"
  timeout $(( $(left) - 5 )) $M pretrain $D/source.zarr --extra $D/extra.zarr --codec-step 1.0 --out $R/$1 \
    --params params.yaml --epochs $2 --replicates $3 --workers $NC --draw-workers $4 --device $DEV > $L/pretrain_$1.json 2> $L/pretrain_$1.log \
    || { log "pretrain $1 failed or ran out of time"; tail -3 $L/pretrain_$1.log; return 1; }
  echo "RESULT pretrain $1 $(tail -1 $L/pretrain_$1.log)" | tee -a "$OUT/progress.txt"
}
finetune() {  # name draw-workers
  for p in nominal d05; do
    timeout $(( $(left) - 5 )) $M train $D/$p.zarr --source $D/source.zarr --codec-step 1.0 --init $R/$1 --epochs 4 \
      --out $R/$1_$p --params params.yaml --workers $NC --draw-workers $2 --device $DEV > $L/train_$1_$p.json 2> $L/train_$1_$p.log \
      || { log "train $1 $p failed"; tail -3 $L/train_$1_$p.log; return 1; }
    $M evaluate $D/$p.zarr --model $R/$1_$p --out $OUT/metrics_$1_$p.json --device $DEV > $L/evaluate_$1_$p.json 2> $L/evaluate_$1_$p.log \
      || { log "evaluate $1 $p failed"; tail -3 $L/evaluate_$1_$p.log; return 1; }
    python3 -c "
import json, math
from metraw.spec.aggregate import iou_measurement
d = json.load(open('$OUT/metrics_$1_$p.json')); iou, var = iou_measurement(d, '$1 $p')
print('RESULT iou $1 $p %.4f +- %.4f (replicate sd %s, %d replicates, %d test images), device %s'
      % (iou, math.sqrt(var), d.get('iou_replicate_sd'), d.get('n_replicates', 1), d['n_images'], d['device']))
" | tee -a "$OUT/progress.txt"
    echo "RESULT train $1 $p $(tail -1 $L/train_$1_$p.log)" | tee -a "$OUT/progress.txt"
  done
}
# 1. draws in the training thread against draw processes: 5 epochs, 1 replicate each (the fields are built anew)
pretrain speed0 $ESPEED 1 0
pretrain speedN $ESPEED 1 $DW
# 2. the default pretraining (20 epochs, 3 replicates) on CUDA, fine-tuned and scored at both points
pretrain e$EDEF $EDEF 3 $DW && finetune e$EDEF $DW
# 3. more epochs in the time left (fields ~15 s, fine-tune + evaluate ~60 s): the steps per second of step 2
SEC=$(python3 -c "
import re; s = open('$L/pretrain_e$EDEF.log').read().splitlines()[-1]
m = re.search(r'in ([0-9.]+) s \(fields ([0-9.]+) s\)', s); print(float(m.group(1)) / $EDEF)" 2>/dev/null || echo 0)
EP=$(python3 -c "print(min(160, int(($(left) - 100) / max($SEC, 1e-9))) if $SEC > 0 else 0)")
log "seconds per epoch (3 replicates) $SEC; epochs that fit: $EP"
if [ "$EP" -ge "$EMIN" ]; then pretrain e$EP $EP 3 $DW && finetune e$EP $DW; fi
log "done"
