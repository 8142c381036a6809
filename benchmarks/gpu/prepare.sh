#!/usr/bin/env bash
# Run HERE (a machine with pip and the package index) before a GPU session: the GPU machine
# has torch, numpy and tqdm but neither PyAV nor pydantic, and no network. This puts their
# wheels (CPython 3.12, x86-64), the published CGVQM weights and half the demo study (one
# scene, 24 conditions, for run.sh precision) into .whl/ (git-ignored, under the 64 MiB a
# device call carries), which the device call carries:  carry [".whl"], command "bash benchmarks/gpu/run.sh STEP".
set -euo pipefail
cd "$(git rev-parse --show-toplevel)"
exclude="$(git rev-parse --git-path info/exclude)"
mkdir -p "$(dirname "$exclude")"
grep -qxF '/.whl/' "$exclude" 2>/dev/null || echo '/.whl/' >> "$exclude"
mkdir -p .whl
PY=.venv/bin/python
[ -x "$PY" ] || PY=python3
"$PY" -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 \
    --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 -d .whl \
    av==18.1.0 pydantic==2.14.4 pydantic-core==2.50.5 annotated-types==0.8.0 \
    typing-inspection==0.4.5 typing-extensions==4.16.0
weights=../shared/data/cgvqm_upstream
if [ -f "$weights/cgvqm-2.pickle" ]; then
    mkdir -p .whl/cgvqm_upstream && cp "$weights"/cgvqm-*.pickle .whl/cgvqm_upstream/
fi
if [ -x .venv/bin/cgvq-study ]; then  # made by make install
    .venv/bin/cgvq-study synth --out .whl/demo --scenes colonnade --no-progress --overwrite
fi
du -sh .whl
