#!/usr/bin/env bash
# Table 3 (and Table 4) of the paper: train both of its rows (the paper's models and ablations, and the Chart-based
# method of Smith et al. 2020 from the view, from touches and from both), then print the chamfer tables.
#
#   examples/reproduce_table3.sh            # the CPU proxy: data=paper_cpu (Table 1's sizes, half the authors' grid)
#   examples/reproduce_table3.sh --gpu      # the paper's recipe: data=paper (the authors' pad and grid), trainer=gpu
#   examples/reproduce_table3.sh --tiny     # the same pipeline at toy size in about a minute (what CI runs)
#
# Each mode generates its data (cached and resumable: rerun the script after an interruption), trains one run per
# model into one multirun folder (logs/train/multiruns/table3_<mode>_<time>/<num>_<experiment>) and evaluates that
# folder with eval.py, which prints Tables 3 and 4 and writes them (Markdown + CSV) to logs/eval/runs/<time>/tables. Extra arguments go to train.py, e.g.
# `examples/reproduce_table3.sh seed=43` or `examples/reproduce_table3.sh trainer.max_epochs=30`. The environment
# variables LOG_DIR (default logs) and CACHE_DIR (default data/cache) move the runs and the data elsewhere.
# The page docs/guides/evaluation.md explains the tables; docs/guides/training.md the experiments.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PY:-.venv/bin/python}
[ -x "$PY" ] || PY=python
LOG_DIR=${LOG_DIR:-logs}
paths=("paths.log_dir=$LOG_DIR")
generate=()
if [ -n "${CACHE_DIR:-}" ]; then
  paths+=("paths.cache_dir=$CACHE_DIR")
  generate=("cache_dir=$CACHE_DIR")
fi

mode=cpu
if [ "${1:-}" = "--tiny" ] || [ "${1:-}" = "--gpu" ] || [ "${1:-}" = "--cpu" ]; then
  mode=${1#--}
  shift
fi

# the paper's model (visual only, tactile only, the full model), Table 4's ablations and the Chart-based row
models=full,visual_only,tactile_only,no_gap,no_direction,region_1x1,region_5x5,single_stage
models+=,chart_based,chart_based_visual,chart_based_tactile
charts=()  # tiny mode trains the Chart-based row in a second sweep into the same folder, at its own toy size
case $mode in
  cpu)
    data=(data=paper_cpu)
    "$PY" -m tvrecon.data.generate preset=paper_cpu ${generate[@]+"${generate[@]}"}
    train=(trainer.max_epochs=8) ;;
  gpu)
    data=(data=paper trainer=gpu)
    "$PY" -m tvrecon.data.generate preset=paper sim_device=cuda ${generate[@]+"${generate[@]}"}
    train=() ;;
  tiny)
    # two models of each row, tiny data, one short epoch: checks the pipeline end to end, not the numbers
    models=full,visual_only
    charts=(chart_based,chart_based_visual trainer.max_epochs=1 ++model.net.chart_deformer.hidden=16
            ++model.net.chart_deformer.num_layers=2)
    data=(data=tiny data.train.num_samples=2 data.val.num_samples=1 data.test.num_samples=2 torch_threads=1)
    train=(trainer.max_epochs=1 model.net.deformer.hidden=16 model.net.deformer.num_blocks=1) ;;
esac

dir=$LOG_DIR/train/multiruns/table3_${mode}_$(date +%Y-%m-%d_%H-%M-%S)
"$PY" train.py -m "experiment=$models" "${data[@]}" ${train[@]+"${train[@]}"} "${paths[@]}" "hydra.sweep.dir=$dir" "$@"
if [ ${#charts[@]} -gt 0 ]; then
  "$PY" train.py -m "experiment=${charts[0]}" "${data[@]}" "${charts[@]:1}" "${paths[@]}" "hydra.sweep.dir=$dir" "$@"
fi
"$PY" eval.py "run_dir=$dir" "${paths[@]}"
echo "Tables 3 and 4: $dir"
