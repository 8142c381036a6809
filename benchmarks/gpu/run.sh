#!/usr/bin/env bash
# Run ON THE GPU MACHINE (after benchmarks/gpu/prepare.sh here; carry .whl). One step per
# call, each well inside the 10-minute limit of one command; outputs go to $OUT:
#   tests     the CUDA tests (tests/cgvqm_core/test_cuda.py) and the pipeline tests
#   cgvqm     benchmarks/bench_cgvqm.py --device cuda (precisions, upstream as run, tf32
#             configurations, batch sweep, pairs/min, breakdown)
#   dataset   benchmarks/bench_dataset.py --device cuda, both variants
#   trace     one pair under torch.profiler (a Perfetto trace) and the breakdown alone
set -euo pipefail
step=${1:?usage: run.sh tests|cgvqm|dataset|trace}
out=${OUT:-/tmp/out}
mkdir -p "$out"
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
    --target /tmp/site .whl/*.whl
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
[ -d .whl/cgvqm_upstream ] && export CGVQM_WEIGHTS_DIR=$PWD/.whl/cgvqm_upstream
python3 -c 'import torch; print("torch", torch.__version__, "CUDA", torch.version.cuda,
"cuDNN", torch.backends.cudnn.version(), torch.cuda.get_device_name())'
case "$step" in
    tests)
        python3 -m pytest -q -p no:cacheprovider tests/cgvqm_core/test_cuda.py \
            tests/cgvqm_core/test_pipeline.py tests/cgvqm_core/test_parity.py 2>&1 \
            | tee "$out/tests_cuda.txt" ;;
    cgvqm)
        python3 benchmarks/bench_cgvqm.py --device cuda --json "$out/bench_cgvqm_cuda.json" \
            2>&1 | tee "$out/bench_cgvqm_cuda.txt" ;;
    dataset)
        python3 benchmarks/bench_dataset.py --device cuda --variants cgvqm-2,cgvqm-5 \
            --json "$out/bench_dataset_cuda.json" 2>&1 | tee "$out/bench_dataset_cuda.txt" ;;
    trace)
        python3 benchmarks/bench_cgvqm.py --device cuda --breakdown-only --trace "$out" \
            2>&1 | tee "$out/bench_breakdown_cuda.txt" ;;
    *) echo "unknown step $step" >&2; exit 2 ;;
esac
