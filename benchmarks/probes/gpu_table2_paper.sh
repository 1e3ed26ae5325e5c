#!/bin/bash
# Table 2 at the paper's size on one GPU, in one device call of about 9.5 minutes:
# cls_paper (the authors' 61x61x10 pad on the 128 grid, 7,700 touches, shared_base) generated on the GPU with one
# worker per host core (~7.6 min on an H100, 2026-11-27: train 268 s, val 65 s, test ~125 s), then the paper's
# classifier on it, four runs at once (~100 s for the four on an H100), results under $OUT (default ./gpu_table2_out).
# A call cut short leaves the cache in $CACHE: a second call on the same warm machine makes only what is missing.
#
#   bash benchmarks/probes/gpu_table2_paper.sh                      # BUDGET=585 seconds in all; WORKERS=<host cores>
#
# A smoke run of the same steps on a CPU (3 objects a split, one epoch):
#   SIM_DEVICE=cpu WORKERS=2 GEN_ARGS="train.num_objects=3 val.num_objects=3 test.num_objects=3" \
#   TRAIN_ARGS="trainer.accelerator=cpu trainer.precision=32-true data.train.num_objects=3 data.val.num_objects=3 \
#   data.test.num_objects=3 trainer.max_epochs=1" bash benchmarks/probes/gpu_table2_paper.sh
#
# Missing Python packages travel as wheels in .whl/ (docs/guides/gpu.md, "A machine with no network"); they are installed
# into /tmp/site when the project's packages are not importable. Each step is bounded so that the results of the steps done come back.
set -u
OUT=${OUT:-$PWD/gpu_table2_out}; mkdir -p "$OUT"
S=$(date +%s); DL=$((S + ${BUDGET:-585}))
left() { echo $((DL - $(date +%s))); }
say() { echo "[$(($(date +%s) - S))s] $*" | tee -a "$OUT/summary.txt"; }
if ! python3 -c "import hydra, trimesh, embreex, kornia, shapely, manifold3d" 2>/dev/null && ls .whl/*.whl >/dev/null 2>&1; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 1
  export PYTHONPATH=/tmp/site:$PWD
fi
export PROJECT_ROOT=$PWD PYTHONUNBUFFERED=1 TQDM_MININTERVAL=15
CACHE=${CACHE:-/tmp/cache}
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader 2>/dev/null | tee -a "$OUT/summary.txt"
say "generate cls_paper (bounded at $(($(left) - 110)) s)"
timeout $(($(left) - 110)) python3 -m tvrecon.data.generate preset=cls_paper workers=${WORKERS:-$(nproc)} \
  library.protocol=shared_base sim_device=${SIM_DEVICE:-cuda} cache_dir="$CACHE" ${GEN_ARGS:-} >"$OUT/generate.log" 2>&1
say "generate rc=$?"; grep -a "^\[" "$OUT/generate.log" | tee -a "$OUT/summary.txt"
grep -aq "^\[test\] .* generated" "$OUT/generate.log" || { say "cls_paper incomplete: no training"; exit 1; }
RUNS=${RUNS:-/tmp/runs}; mkdir -p "$RUNS"; pids=""
for run in "10 112 0" "10 112 1" "10 112 2" "1 112 0"; do
  set -- $run; name=n$1_px$2_seed$3
  timeout $(($(left) - 15)) python3 train.py experiment=classify_paper_cpu data=cls_paper \
    data.library.protocol=shared_base trainer=gpu trainer.precision=bf16-mixed paths.cache_dir="$CACHE" \
    data.tactile_size=61 data.device_tactile_size=$2 data.num_workers=0 torch_threads=3 model.num_touches=$1 \
    seed=$3 hydra.run.dir="$RUNS/$name" ${TRAIN_ARGS:-} >"$RUNS/$name.log" 2>&1 &
  pids="$pids $!"
done
say "training 4 runs (bounded at $(($(left) - 15)) s)"; wait $pids; say "training done"
for f in "$RUNS"/*.log; do echo "== $(basename "$f")"; grep -a "test/acc@" "$f" | tail -3; done | tee -a "$OUT/summary.txt"
tar czf "$OUT/runs.tgz" --exclude='*.ckpt' -C "$(dirname "$RUNS")" "$(basename "$RUNS")"
