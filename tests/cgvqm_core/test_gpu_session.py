"""benchmarks/gpu/session.py, the one-call GPU session: its deadline rules, its summary, the
authors'-code reader, and (slow) a rehearsal of every section at tiny sizes on this CPU.

A GPU lease is short and rare; a fault found there costs the lease, so it is found here.
"""

from __future__ import annotations

import argparse
import importlib
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
GPU_DIR = ROOT / "benchmarks" / "gpu"


def _session(session, tmp_path: Path, budget: float):
    args = argparse.Namespace(rehearse=False, json=tmp_path / "s.json", device="cpu")
    ss = session.Session(args, session.Sizes.rehearsal(), ["fp32"], bb=None)
    ss.deadline = time.monotonic() + budget
    return ss


def test_sections_run_in_order_are_skipped_when_short_and_cut_at_the_deadline(
        session, tmp_path, monkeypatch):
    calls: list[str] = []

    def quick(_ss):
        calls.append("quick")
        return {"x": 1}

    def broken(_ss):
        calls.append("broken")
        raise ValueError("boom")

    def slow(_ss):
        calls.append("slow")
        time.sleep(10)
        return {}

    def never(_ss):
        calls.append("never")
        return {}

    monkeypatch.setattr(session, "PLAN", [
        ("quick", 0, quick), ("broken", 0, broken), ("big", 60, never), ("slow", 0.1, slow),
        ("after", 0, never)])
    ss = _session(session, tmp_path, 1.0)
    t0 = time.monotonic()
    session.run_plan(ss, None)
    assert time.monotonic() - t0 < 3  # the alarm cut the 10 s section at the 1 s deadline
    assert calls == ["quick", "broken", "slow"]
    saved = json.loads((tmp_path / "s.json").read_text())
    status = {k: v["status"] for k, v in saved["sections"].items()}
    assert status["quick"] == "done" and saved["quick"] == {"x": 1}
    assert status["broken"] == "error: ValueError: boom"
    assert "ValueError" in saved["sections"]["broken"]["traceback"]
    assert status["big"].startswith("skipped") and "estimate 60 s" in status["big"]
    assert status["slow"] == "cut at the deadline"
    assert "after" not in status  # nothing starts after the deadline
    # the alarm is off again: a later sleep is not interrupted
    time.sleep(0.05)


def test_what_a_section_measured_before_the_deadline_is_kept(session, tmp_path, monkeypatch):
    """fastpath's way: figures filled into :meth:`Session.partial` as they come."""
    def measuring(ss):
        out = ss.partial("measuring")
        for config in ("first", "second"):
            out[config] = {"pairs_per_min": 1.0}
            ss.save()
            time.sleep(0.6)  # the second waits past the 1 s deadline
        return out

    monkeypatch.setattr(session, "PLAN", [("measuring", 0, measuring)])
    session.run_plan(_session(session, tmp_path, 1.0), None)
    saved = json.loads((tmp_path / "s.json").read_text())
    assert saved["sections"]["measuring"]["status"] == "cut at the deadline"
    assert saved["measuring"] == {"first": {"pairs_per_min": 1.0},
                                  "second": {"pairs_per_min": 1.0}}


def test_configuration_labels_become_cgvqm_arguments(session):
    import inspect

    from cgvqm_core import CGVQM

    parse = session.parse_config
    assert parse("fp16+splitstem+s2d") == ("fp16", {"split_stem": "int", "stem_2d": True,
                                                    "stem_s2d": True})
    assert parse("bf16+s2d")[1]["differences"] is False  # a 2D stem: no differences
    assert parse("bf16-plain") == ("bf16", {"differences": False})
    with pytest.raises(ValueError, match=r"unknown option \+phases"):
        parse("fp16+phases")
    # every label the sessions use names arguments CGVQM takes
    known = set(inspect.signature(CGVQM).parameters)
    bench = sys.modules[session.parse_config.__module__]
    for option in bench.OPTIONS.values():
        assert set(option) <= known, option


def test_only_runs_the_named_sections(session, tmp_path, monkeypatch):
    ran: list[str] = []
    monkeypatch.setattr(session, "PLAN", [
        (n, 0, lambda _ss, n=n: ran.append(n) or {}) for n in ("a", "b", "c")])
    session.run_plan(_session(session, tmp_path, 5.0), ["c", "a"])
    assert ran == ["a", "c"]  # the plan's order, not the request's


def test_summary_says_not_measured_for_what_did_not_run(session, targets, tmp_path):
    ss = _session(session, tmp_path, 1.0)
    ss.precs = ["fp32", "bf16"]
    lines = targets.summary(ss)
    assert len(lines) == 8 and all(line.rstrip().endswith("not measured") for line in lines)
    assert targets.many_gpus(ss)[0].startswith("many GPUs: not modelled")


def test_summary_judges_the_targets_from_the_figures(session, targets, tmp_path):
    ss = _session(session, tmp_path, 1.0)
    ss.precs = ["fp32", "tf32", "bf16", "fp16"]
    ss.fig.update({
        "defaults": {"auto": {"single_x": 1.6, "dq_vs_upstream": 2e-4}},
        "paper_set": {"x": 2.4, "max_dq": 1e-4},
        "shares": {"bf16": {"backbone_share": 0.61, "wall_share": 0.5},
                   "fp16": {"backbone_share": 0.59, "wall_share": 0.5}},
        "throughput": {"fp16/reuse4/batch=default": {"pairs_per_min": 351.0},
                       "auto/reuse4/batch=default": {"pairs_per_min": 300.0},
                       "auto/single/batch=default": {"pairs_per_min": 400.0}},
        "parity": {"cgvqm-2": {"max_pool": 1e-6, "mean_pool": 2e-6, "ok": True}},
        "drift": {"figures": {"results": [
            {"variant": "cgvqm-2", "other": {
                "bf16": {"max_pool": {"max": 0.02}, "mean_pool": {"max": 0.01}},
                "fp16": {"max_pool": {"max": 0.001}, "mean_pool": {"max": 0.002}}}},
            {"variant": "cgvqm-5", "other": {
                "bf16": {"max_pool": {"max": 0.07}, "mean_pool": {"max": 0.03}},
                "fp16": {"max_pool": {"max": 0.004}, "mean_pool": {"max": 0.003}}}}]}},
        "breakdown": {"decode_one_video_s": 0.8, "fp16": {"pairs_per_min": 200.0}},
        "stem_kernels": {  # the TF32 stem is fastest, but not fp32's numbers
            "fp32": {"s_per_pair": 0.10, "error_vs_fp64": 1e-7},
            "fp32-2d": {"s_per_pair": 0.035, "error_vs_fp64": 1.5e-7},
            "tf32-pad": {"s_per_pair": 0.02, "error_vs_fp64": 3e-4}},
    })
    lines = targets.summary(ss)
    verdict = {line.split("  ")[1].strip()[:12]: line.rstrip().rsplit(" ", 1)[-1]
               for line in lines}
    assert verdict["stem alone w"] == "met"
    assert "0.0350 s (fp32-2d)" in next(x for x in lines if "stem alone" in x)
    assert verdict["default on c"] == "met"  # x1.6 >= x1.5 at |dq| 2e-4
    assert verdict["default: pap"] == "MISSED"  # x2.4 < x2.5
    assert verdict["bf16: backbo"] == "met" and verdict["fp16: backbo"] == "MISSED"
    assert verdict["bf16/fp16: >"] == "met"  # 351 from fp16
    assert verdict["bf16: |dq| a"] == "MISSED" and verdict["fp16: |dq| a"] == "met"
    assert targets.drift_worst(ss.fig["drift"])["bf16"] == (0.07, "cgvqm-5, max pooling")
    model = targets.many_gpus(ss)[0]
    # one GPU reads files at 200 pairs/min (351 from memory); a pair decodes 1.25 videos =
    # 1.0 s of a core
    assert "N x 200 pairs/min" in model and "351 from memory" in model
    assert "1.00 s of one core per pair" in model
    # the host's measured decoding ceiling, and fast paths: the fastest within the bound
    # counts, one over the drift bound (on the demo) does not
    ss.fig["decoding"] = {"threads_pairs_per_min": 270.0, "processes_pairs_per_min": 300.0}
    ss.fig["fastpath"] = {"fp16": {"pairs_per_min": 380.0, "max_dq_vs_fp32": 2e-3,
                                   "backbone_share": 0.7},
                          "bf16+x": {"pairs_per_min": 390.0, "max_dq_vs_fp32": 3e-3,
                                     "backbone_share": 0.8}}
    ss.fig["fast_drift"] = {"figures": {"results": [{"variant": "cgvqm-5", "other": {
        "fp16": {"max_pool": {"max": 0.03}, "mean_pool": {"max": 0.01}},
        "bf16+x": {"max_pool": {"max": 0.08}, "mean_pool": {"max": 0.01}}}}]}}
    model = targets.many_gpus(ss)[0]
    assert "380 from memory" in model and "measured at 300 pairs/min" in model
    assert "N <= 1.5 GPUs" in model  # 300 / 200
    rows = [line for line in targets.summary(ss) if "fast paths" in line]
    assert "380 (fp16)" in rows[0] and rows[0].endswith("met")
    assert "70 % (fp16)" in rows[1] and rows[1].endswith("met")
    # real content has the last word: over the bound there, a fast path no longer counts
    ss.fig["real_drift"] = {"figures": {"results": [{"variant": "cgvqm-2", "other": {
        "fp16": {"max_pool": {"max": 0.07}, "mean_pool": {"max": 0.01}}}}]}}
    assert targets.fast_within_bound(ss.fig) == {}
    rows = [line for line in targets.summary(ss) if "real content" in line]
    assert len(rows) == 1 and "fp16" in rows[0] and rows[0].endswith("MISSED")


def test_real_clips_become_clips_and_pristine_distorted_pairs(session, tmp_path):
    for name in ("bikes", "carphone_pristine", "carphone_distorted", "lonely_pristine", "a"):
        (tmp_path / f"{name}.mp4").write_bytes(b"")
    (tmp_path / "notes.txt").write_text("not a clip")
    got = session.real_args(tmp_path)
    assert got == ["--real", str(tmp_path / "a.mp4"), "--real", str(tmp_path / "bikes.mp4"),
                   "--real-pair", f"{tmp_path / 'carphone_pristine.mp4'},"
                                  f"{tmp_path / 'carphone_distorted.mp4'}",
                   "--real", str(tmp_path / "lonely_pristine.mp4")]  # no partner: a clip
    assert session.real_args(tmp_path / "none") == []


def test_the_pyav_reader_keeps_read_videos_contract(tmp_path):
    """The stand-in for torchvision.io.read_video that the authors' code gets where a newer
    torchvision dropped it: uint8 frames in TCHW order, exactly the pixels, and the rate."""
    sys.path.insert(0, str(GPU_DIR))
    try:
        upstream_own = importlib.import_module("upstream_own")
    finally:
        sys.path.remove(str(GPU_DIR))
    from stimuli_manifests import write_video

    rng = np.random.default_rng(3)
    frames = rng.integers(0, 256, (5, 24, 40, 3), dtype=np.uint8)
    path = write_video(tmp_path / "v.mkv", frames, 25)  # lossless
    vid, audio, info = upstream_own.read_video_pyav(str(path), output_format="TCHW",
                                                    pts_unit="sec")
    assert vid.dtype.is_floating_point is False and tuple(vid.shape) == (5, 3, 24, 40)
    np.testing.assert_array_equal(vid.permute(0, 2, 3, 1).numpy(), frames)
    assert info == {"video_fps": 25.0} and audio.numel() == 0
    thwc, _, _ = upstream_own.read_video_pyav(str(path))
    assert tuple(thwc.shape) == (5, 24, 40, 3)
    assert upstream_own.missing_files(tmp_path)  # an empty folder is no copy of their code


@pytest.mark.slow
def test_the_session_rehearses_every_section_on_a_cpu(tmp_path):
    """Every section at tiny sizes in a child process, as on the GPU machine but on a CPU.
    The authors' code section needs the copy prepare.sh makes; without it, it must say so."""
    out = tmp_path / "session.json"
    sections = ("parity,defaults,paper_set,shares,throughput,stem,breakdown,upstream_own,"
                "differences,cgvqm5_defaults,cgvqm5_set,cgvqm5_shares,tests,trace")
    run = subprocess.run([sys.executable, str(GPU_DIR / "session.py"), "--rehearse",
                          "--budget", "600", "--only", sections, "--json", str(out)],
                         capture_output=True, text=True, cwd=ROOT, timeout=900)
    assert run.returncode == 0, run.stderr[-2000:]
    fig = json.loads(out.read_text())
    status = {k: v["status"] for k, v in fig["sections"].items()}
    no_copy = not (ROOT / ".whl" / "upstream" / "cgvqm.py").is_file()
    from cgvqm_core.precision import cpu_bf16

    for name in sections.split(","):
        if name == "upstream_own" and no_copy:
            assert status[name].startswith("error: FileNotFoundError: no copy"), status[name]
        elif name == "differences" and not cpu_bf16().supported:  # bf16 only: said so
            assert status[name] == "skipped: bf16 is not offered here", status[name]
        else:
            assert status[name] == "done", (name, status[name],
                                            fig["sections"][name].get("traceback"))
    assert fig["tests"]["rc"] == 0
    assert max(r["max_pool"] for r in fig["parity"].values()) == 0  # the CPU against itself
    assert fig["defaults"]["auto"]["dq_vs_upstream"] < 1e-3
    assert "the issue's targets" in run.stdout
    assert fig["summary"][0].lstrip().startswith("default on cpu: single pair")
