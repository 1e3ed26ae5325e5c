#!/bin/bash
# One device call: cls_paper generated on the GPU, the paper's classifier on it, then the press bench (bench_gpu.py).
set -u
S=$(date +%s); DL=$((S+${BUDGET:-575}))
left(){ echo $(( DL - $(date +%s) )); }
stamp(){ echo "[$(( $(date +%s) - S ))s] $*" | tee -a $OUT/summary.txt; }
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee -a $OUT/summary.txt
[ -n "${SKIP_PIP:-}" ] || python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 1
export PYTHONPATH=/tmp/site:$PWD PROJECT_ROOT=$PWD PYTHONUNBUFFERED=1 TQDM_MININTERVAL=15
python3 -c "import torch,sys;print(sys.version.split()[0],torch.__version__,torch.cuda.get_device_name())" | tee -a $OUT/summary.txt
stamp "generate start (timeout $(( $(left) - 230 ))s)"
timeout $(( $(left) - 230 )) python3 -m tvrecon.data.generate preset=cls_paper workers=16 library.protocol=shared_base \
  sim_device=${DEV:-cuda} cache_dir=/tmp/cache ${GEN_EXTRA:-} > $OUT/gen.log 2>&1; G=$?
stamp "generate rc=$G"; grep -a "^\[" $OUT/gen.log | tee -a $OUT/summary.txt
mkdir -p /tmp/runs
if [ $G = 0 ]; then
  T="python3 train.py experiment=classify_paper_cpu data=cls_paper data.library.protocol=shared_base trainer=gpu \
     trainer.precision=bf16-mixed paths.cache_dir=/tmp/cache data.tactile_size=61 data.num_workers=0 torch_threads=3 ${TRAIN_EXTRA:-}"
  P=""
  for r in "10 112 0" "10 112 1" "1 112 0" "10 224 0"; do set -- $r
    $T data.device_tactile_size=$2 model.num_touches=$1 seed=$3 hydra.run.dir=/tmp/runs/n$1_s$2_seed$3 > /tmp/runs/n$1_s$2_seed$3.log 2>&1 &
    P="$P $!"
  done
  stamp "train start (timeout $(( $(left) - 75 ))s)"
  ( sleep $(( $(left) - 75 )); pkill -f train.py ) & K=$!
  wait $P; kill $K 2>/dev/null
  stamp "train done"
  for f in /tmp/runs/*.log; do echo "== $f"; grep -a "test/acc@\|Tactile classifier \|Epoch .*100%" $f | tail -4; done | tee -a $OUT/summary.txt
  tar czf $OUT/runs.tgz --exclude='*.ckpt' -C /tmp runs
fi
stamp "bench setup-processes (timeout $(left)s)"
timeout $(left) python3 benchmarks/bench_gpu.py --device ${DEV:-cuda} --scenes paper --modes eager --batches 64 --count-batch 0 \
  --setup-processes 0,16 --out $OUT/bench_setup.json > $OUT/bench_setup.log 2>&1; stamp "bench rc=$?"
if [ $(left) -gt 140 ]; then
  stamp "bench compiled (timeout $(left)s)"
  timeout $(left) python3 benchmarks/bench_gpu.py --device ${DEV:-cuda} --scenes paper --modes compiled --batches 64 --count-batch 0 \
    --out $OUT/bench_compiled.json > $OUT/bench_compiled.log 2>&1; stamp "bench compiled rc=$?"
fi
tail -n 5 $OUT/bench_*.log
