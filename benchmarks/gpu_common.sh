# Sourced by the device scripts (benchmarks/gpu_chain.sh, benchmarks/gpu_scale.sh), from the repository root, with
# BUDGET (seconds) and OUT set: the environment (wheels in .whl/ where the machine lacks zarr or jsonschema, metraw
# from src/), the helpers log / left / point, and gpu_data, which makes the default data of a run: NS source scenes
# (seed 0) and NX pretraining scenes (seed 1) of SIZE px, quantised at the codec's step 1 and stored decoded, and the
# nominal and D 0.5 m test stores ($D/nominal.zarr, $D/d05.zarr).
# The H200 image (Python 3.12, torch 2.11, numba, scipy, pandas there) lacked eight packages on 2026-11-28; made here
# (ignored by .git/info/exclude: /.whl/) and carried (`carry: [".whl"]`, 9.8 MB):
#   python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
#     --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 -d .whl \
#     zarr==3.1.6 numcodecs==0.16.6 donfig==0.8.1.post1 google-crc32c==1.9.0 jsonschema==4.26.0 \
#     jsonschema-specifications==2025.9.1 referencing==0.37.0 rpds-py==2026.9.1
T0=$(date +%s); DEADLINE=$((T0 + BUDGET))
: "${OUT:?set OUT to a directory for the results}"
NS=${NS:-480}; NX=${NX:-960}; SIZE=${SIZE:-1024}; DEV=${DEV:-cuda}
export PYTHONUNBUFFERED=1
L=$OUT/logs; mkdir -p "$L"
log() { echo "[$(( $(date +%s) - T0 )) s] $*" | tee -a "$OUT/progress.txt"; }
left() { echo $(( DEADLINE - $(date +%s) )); }
if [ -d .whl ] && ! python3 -c "import zarr, jsonschema" 2>/dev/null; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \
    || { log "wheel install failed"; exit 1; }
  export PYTHONPATH=/tmp/site
fi
export PYTHONPATH=$PWD/src${PYTHONPATH:+:$PYTHONPATH}
M="python3 -m metraw"
# the scene workers split in proportion to the scenes (480 + 960 on 16 cores: 5 + 11), the emulations take W2 each
NC=$(nproc); W1=$(( NC * NS / (NS + NX) )); W1=$(( W1 > 0 ? W1 : 1 )); W2=$(( NC - W1 > 0 ? NC - W1 : 1 ))
python3 -c "import torch, numpy, numba, zarr; print('torch', torch.__version__, 'cuda', torch.cuda.is_available(),
torch.cuda.get_device_name(0) if torch.cuda.is_available() else '', 'numpy', numpy.__version__, 'numba', numba.__version__,
'zarr', zarr.__version__)" 2>&1 | tee -a "$OUT/progress.txt"
WORK=${WORK:-/tmp/metraw_gpu}; rm -rf "$WORK"; D=$WORK/d; R=$WORK/r; mkdir -p $D $R  # stores and models (~2.5 GB)
point() { python3 -c "
from metraw.study.points import load_params, target_params
t = target_params(load_params('params.yaml'), '$1')
print(','.join(f'{k}={v}' for k, v in t.items() if not isinstance(v, (dict, list))))"; }

gpu_data() {
  local nom d05 p P
  nom=$(point nominal) && d05=$(point diameter_m-0.5) || { log "points failed"; return 1; }
  log "scenes: $NS source (seed 0) + $NX pretraining (seed 1), $SIZE px, quantised and stored decoded"
  $M scenes --n $NS --seed 0 --size $SIZE --camera params.yaml --out $D/source.zarr --workers $W1 \
    --codec-step 1.0 --codec-seed 0 --codec-decoded 2> $L/scenes_source.log &
  $M scenes --n $NX --seed 1 --size $SIZE --camera params.yaml --out $D/extra.zarr --workers $W2 \
    --codec-step 1.0 --codec-seed 0 --codec-decoded 2> $L/scenes_extra.log &
  wait
  tail -q -n 1 $L/scenes_source.log $L/scenes_extra.log | tee -a "$OUT/progress.txt"
  [ -d $D/extra.zarr ] && [ -d $D/source.zarr ] || { log "scenes failed"; return 1; }
  log "emulate the nominal and D 0.5 m test stores"
  for p in nominal d05; do
    P=$nom; [ $p = d05 ] && P=$d05
    $M emulate $D/source.zarr $D/$p.zarr --params params.yaml --point "$P" --mode auto --seed 0 --images test \
      --workers $W2 --codec-step 1.0 --codec-seed 0 2> $L/emulate_$p.log &
  done
  wait
  [ -d $D/nominal.zarr ] && [ -d $D/d05.zarr ] || { log "emulate failed"; tail -3 $L/emulate_*.log; return 1; }
  log "data ready"
}
