#!/bin/bash
# Pretraining past the 2-core budget on a GPU machine (issue #15's learning curve): the default data (480 source
# scenes, NX pretraining scenes), then benchmarks/pretrain_scale.py's VARIANTS side by side on the device, each scored
# alone (the pretrained network, as the workflow's robust model) on the nominal and D 0.5 m test stores.
# Run from the repository root: OUT=dir bash benchmarks/gpu_scale.sh [BUDGET_S, default 560]; RESULT lines in
# $OUT/progress.txt. A dry run on a CPU:
# OUT=/tmp/o NS=12 NX=8 SIZE=256 DEV=cpu VARIANTS=b8e1,b16e2,b8e1s10w1 bash benchmarks/gpu_scale.sh 600
# Measured 2026-11-27 on one H100 (16 cores): data 170 s (scenes 122 s, test stores 35 s), fields 37 s; b8e20 and
# b32e80 side by side with three longer variants: 159 s and 180 s, nominal 0.220 / 0.247, D 0.5 m 0.280 / 0.301;
# b64e160w12 alone (second call): 155 s, 0.259 / 0.315 (docs/training.md, "GPUs"). The default VARIANTS are those three.
# Measured 2026-11-28 on one H200 (16 cores): VARIANTS=b128e280w14, budget 585: data 141 s, fields 35 s, training 206 s,
# whole run 407 s; 0.253 / 0.317, under the line of the three above (the batch past 64 buys less than more steps).
set -uo pipefail
BUDGET=${1:-560}
NX=${NX:-1920}
. benchmarks/gpu_common.sh
VARIANTS=${VARIANTS:-b8e20,b32e80,b64e160w6}
log "cores $NC, budget $BUDGET s, variants $VARIANTS"
gpu_data || exit 1
log "pretrain the variants"
timeout $(( $(left) - 40 )) python3 benchmarks/pretrain_scale.py $D/source.zarr --extra $D/extra.zarr --out $R \
  --variants $VARIANTS --device $DEV --workers $NC 2> $L/scale.log | tee -a "$OUT/progress.txt"
tail -5 $L/scale.log
for m in $R/*/; do
  v=$(basename $m)
  for p in nominal d05; do
    $M evaluate $D/$p.zarr --model $m --out $OUT/metrics_${v}_$p.json --device $DEV > /dev/null 2> $L/evaluate_${v}_$p.log &
  done
done
wait
for f in $OUT/metrics_*.json; do
  python3 -c "
import json, math
from metraw.spec.aggregate import iou_measurement
d = json.load(open('$f')); name = '$f'.rsplit('metrics_', 1)[1][:-5]; iou, var = iou_measurement(d, name)
print('RESULT iou %s %.4f +- %.4f (%d test images; precision %s, recall %s, object F1 %s)' % (name, iou,
      math.sqrt(var), d['n_images'], d['precision'], d['recall'], d.get('object_f1')))
" | tee -a "$OUT/progress.txt"
done
log "done"
