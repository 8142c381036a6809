"""The scoring pipeline's speed features change no number: several patch positions per
network pass, decoding ahead in a thread, the stage clock; and the thread behaves (errors
reach the caller, an early stop stops it)."""

from __future__ import annotations

import threading

import av
import numpy as np
import pytest
import torch

from cgvqm_core import CGVQM
from cgvqm_core.clip_feed import clip_sets
from cgvqm_core.errors import CGVQMError
from cgvqm_core.features import FeatureNet
from cgvqm_core.patch_scorer import CUDA_PASS_VOXELS, PatchScorer, default_batch_size
from cgvqm_core.precision import tf32_mode
from cgvqm_core.stage_clock import STAGES, StageClock
from cgvqm_core.stream import Geometry, padded_clips

from .test_parity import _random_weights, straightforward_cgvqm


def _decode_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name == "cgvqm-decode" and t.is_alive()]


@pytest.mark.parametrize("batch_size", [4, 6, 16])
def test_several_positions_per_pass_match_the_spec(vids, state_dict, backbone, batch_size):
    """Batches of 2, 3 and 8 positions (with a last, smaller group) give the spec's q and
    error map, computed independently one patch at a time."""
    ref = vids.smooth(11, 9, 17, 21)
    test = vids.distort(ref, seed=12)
    weights = _random_weights("cgvqm-2", 131, seed=13)
    metric = CGVQM(weights=weights, backbone=backbone, batch_size=batch_size)
    assert metric.scorer.positions_per_pass(1, 4 * 4 * 5) == batch_size // 2
    res = metric.score(ref, test, fps=4, emap=True)
    q_max, q_mean, emap = straightforward_cgvqm(ref, test, state_dict, weights.omega,
                                                weights.alpha, 3, 4)
    assert res.quality("max") == pytest.approx(q_max, abs=1e-3)
    assert res.quality("mean") == pytest.approx(q_mean, abs=1e-3)
    np.testing.assert_allclose(res.emap, emap, rtol=1e-3, atol=1e-3 * np.abs(emap).max())


def test_grouped_passes_equal_one_position_at_a_time(vids, backbone):
    """Four tests sharing a reference: one position per pass in chunks (batch 2), one
    position per pass (batch 5) and two per pass (batch 10) agree patch by patch, frame by
    frame, and in the error maps."""
    ref = vids.smooth(14, 7, 16, 16)
    tests = [vids.distort(ref, seed=20 + s, sigma=2.0 + s) for s in range(4)]
    weights = _random_weights("cgvqm-2", 131, seed=15)
    runs = {}
    for bs in (2, 5, 10):
        m = CGVQM(weights=weights, backbone=backbone, batch_size=bs)
        runs[bs] = m.score_many(ref, tests, fps=3, emap=[True] * 4)
    assert CGVQM(weights=weights, backbone=backbone, batch_size=10
                 ).scorer.positions_per_pass(4, 100) == 2
    for bs in (5, 10):
        for a, b in zip(runs[2], runs[bs], strict=True):
            np.testing.assert_allclose(b.patch_errors, a.patch_errors, rtol=1e-5, atol=1e-6)
            np.testing.assert_allclose(b.frame_errors, a.frame_errors, rtol=1e-5, atol=1e-6)
            np.testing.assert_allclose(b.emap, a.emap, rtol=1e-4, atol=1e-6)
            assert b.msd.shape == a.msd.shape


def test_prefetch_gives_identical_numbers_and_the_clock_adds_up(vids, backbone):
    """Decoding ahead in a thread computes exactly what the inline run computes; the stage
    clock's stages and idle time add up to the wall time, and the thread is gone after."""
    ref = vids.smooth(16, 10, 16, 16)
    tests = [vids.distort(ref, seed=s) for s in (30, 31)]
    weights = _random_weights("cgvqm-2", 131, seed=16)
    inline_clock, ahead_clock = StageClock(), StageClock()
    inline = CGVQM(weights=weights, backbone=backbone, prefetch=False).score_many(
        ref, tests, fps=4, clock=inline_clock)
    ahead = CGVQM(weights=weights, backbone=backbone, prefetch=True).score_many(
        ref, tests, fps=4, clock=ahead_clock)
    for a, b in zip(inline, ahead, strict=True):
        np.testing.assert_array_equal(a.msd, b.msd)
        np.testing.assert_array_equal(a.frame_errors, b.frame_errors)
    assert not _decode_threads()
    for clock, overlapped in ((inline_clock, False), (ahead_clock, True)):
        s = clock.seconds()
        assert clock.overlapped is overlapped
        assert s["wall"] > 0 and s["backbone"] > 0 and s["pooling"] > 0 and s["decode"] > 0
        on_path = s["copy"] + s["backbone"] + s["pooling"] + s["idle"] + (
            s["wait"] if overlapped else s["decode"])
        assert on_path == pytest.approx(s["wall"], rel=1e-9)
        assert s["backbone"] > s["copy"]  # the network is the work here
        line = clock.report()
        assert all(name in line for name in ("backbone", "pooling", "idle"))
    assert "overlapped" in ahead_clock.report() and "wait" in ahead_clock.report()
    assert inline_clock.seconds()["wait"] == 0.0


def test_profiler_sees_the_stages(vids, backbone):
    """Each stage is a torch.profiler range named cgvqm/<stage>, so a trace shows the same
    split as the clock."""
    ref = vids.smooth(17, 5, 12, 12)
    metric = CGVQM(weights=_random_weights("cgvqm-2", 131, seed=17), backbone=backbone)
    with torch.profiler.profile(activities=[torch.profiler.ProfilerActivity.CPU]) as prof:
        metric.score(ref, vids.distort(ref, seed=18), fps=5, clock=StageClock())
    names = {e.key for e in prof.key_averages()}
    assert {"cgvqm/copy", "cgvqm/backbone", "cgvqm/pooling"} <= names


def _write_mp4(path, frames: np.ndarray, fps: int = 10) -> None:
    with av.open(str(path), "w") as out:
        st = out.add_stream("libx264", rate=fps, options={"crf": "0"})
        st.width, st.height, st.pix_fmt = frames.shape[2], frames.shape[1], "yuv444p"
        for f in frames:
            for pkt in st.encode(av.VideoFrame.from_ndarray(f, format="rgb24")):
                out.mux(pkt)
        for pkt in st.encode():
            out.mux(pkt)


def test_decode_errors_reach_the_caller_through_the_thread(vids, backbone, tmp_path):
    """A test video whose stream ends early fails with the same message with and without
    the decode thread, and leaves no thread behind."""
    ref = vids.smooth(19, 12, 16, 16)
    ref_path, test_path = tmp_path / "ref.mp4", tmp_path / "test.mp4"
    _write_mp4(ref_path, ref)
    _write_mp4(test_path, vids.distort(ref, seed=19))
    weights = _random_weights("cgvqm-2", 131, seed=19)
    from cgvqm_core import stream

    class Short:
        """The test file's frames, one short of what its header promises."""

        def __init__(self) -> None:
            self.inner = stream.open_input(test_path)
            self.info = self.inner.info

        def frames(self):
            for i, f in enumerate(self.inner.frames()):
                if i == self.info.frame_count - 1:
                    return
                yield f

    messages = []
    for prefetch in (False, True):
        m = CGVQM(weights=weights, backbone=backbone, prefetch=prefetch)
        with pytest.raises(CGVQMError, match="decoded 11 frames but its header promises 12"
                           ) as exc:
            m.score(ref_path, Short())
        messages.append(str(exc.value))
    assert messages[0] == messages[1]
    assert not _decode_threads()


def test_an_early_stop_stops_the_decode_threads(vids):
    """A consumer that leaves after one clip set (an error in the network, ^C) does not
    leave the thread decoding the rest of the video."""
    geom = Geometry(frames=40, height=16, width=16, fps=4)
    video = vids.smooth(21, 40, 16, 16)
    feed = clip_sets(padded_clips(iter(video), geom), [padded_clips(iter(video), geom)],
                     prefetch=True)
    first = next(feed)
    assert first.index == 0 and first.valid == 4
    np.testing.assert_array_equal(first.ref.numpy(), video[:4])
    assert len(_decode_threads()) == 2  # one per video: they decode in parallel
    feed.close()
    assert not _decode_threads()


def test_prefetched_clips_are_owned_copies(vids):
    """Clip sets decoded ahead do not share the reused padding buffer: every one still holds
    its own frames after the next ones were decoded (the last clip padded by repetition)."""
    geom = Geometry(frames=10, height=8, width=8, fps=4)
    video = vids.smooth(22, 10, 8, 8)
    sets = list(clip_sets(padded_clips(iter(video), geom), [], prefetch=True))
    assert [s.index for s in sets] == [0, 1, 2] and [s.valid for s in sets] == [4, 4, 2]
    np.testing.assert_array_equal(sets[0].ref.numpy(), video[:4])
    np.testing.assert_array_equal(sets[2].ref.numpy()[:2], video[8:])
    np.testing.assert_array_equal(sets[2].ref.numpy()[2:], video[[9, 9]])


def test_default_batch_and_cudnn_switches(backbone):
    """The device defaults, and cuDNN's benchmark switch set for a run and restored.

    CUDA: 16 patches of a 512x512 video per pass, 4 of a 1024x1024 one, 2 of 1080p (never
    fewer than 2), and a given batch size wins."""
    # CPU: two videos while their largest activation (64 fp32 channels at half the patch's
    # height and width) fits the 32 MiB blocks glibc keeps between passes, else one
    assert default_batch_size("cpu", 30 * 128 * 128) == 1  # 2 x 31.5 MB
    assert default_batch_size("cpu", 30 * 64 * 64) == 2  # 2 x 7.9 MB
    assert default_batch_size("cpu", 16 * 128 * 128) == 2  # 2 x 16.8 MB = 32 MiB
    assert default_batch_size("cpu", 16 * 128 * 128 + 1) == 1
    assert default_batch_size("cpu", 30 * 270 * 480) == 1
    # bf16 differences: reference and tests are separate tensors, blocks of one video each
    assert default_batch_size("cpu", 30 * 128 * 128, separate_reference=True) == 2
    patch = 30 * 128 * 128
    assert PatchScorer(FeatureNet(backbone, 3)).videos_per_pass(patch) == 1
    assert PatchScorer(FeatureNet(backbone, 3, differences=True)).videos_per_pass(patch) == 2
    assert PatchScorer(FeatureNet(backbone, 3), batch_size=5).videos_per_pass(patch) == 5
    assert default_batch_size("cuda", 30 * 128 * 128) == 16
    assert default_batch_size("cuda", 30 * 256 * 256) == 4
    assert default_batch_size("cuda", 30 * 270 * 480) == 2
    assert default_batch_size("cuda", 1) == CUDA_PASS_VOXELS
    saved = torch.backends.cudnn.benchmark
    try:
        torch.backends.cudnn.benchmark = False
        with tf32_mode(torch.device("cuda"), True, benchmark=True):
            assert torch.backends.cudnn.benchmark is True
        assert torch.backends.cudnn.benchmark is False
    finally:
        torch.backends.cudnn.benchmark = saved


def test_all_stages_are_known():
    assert STAGES == ("decode", "wait", "copy", "backbone", "pooling")


def test_more_positions_than_fit_are_refused(backbone):
    sc = PatchScorer(FeatureNet(backbone, 3), None, batch_size=3)
    p = torch.zeros(2, 8, 8, 3, dtype=torch.uint8)
    with pytest.raises(CGVQMError, match="do not fit a batch of 3"):
        sc.compare([p, p], [[p], [p]])


def test_the_benchmarks_upstream_stand_in_computes_cgvqm(vids, state_dict, backbone):
    """benchmarks/upstream_as_run.py, which the speed-ups are measured against, computes the
    spec's q (so a ratio against it compares equal work)."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
    try:
        from upstream_as_run import UpstreamAsRun
    finally:
        sys.path.pop(0)
    ref = vids.smooth(23, 9, 17, 21)
    test = vids.distort(ref, seed=24)
    weights = _random_weights("cgvqm-2", 131, seed=25)
    run = UpstreamAsRun(backbone, weights).score(ref, test, fps=4)
    q_max, q_mean, _ = straightforward_cgvqm(ref, test, state_dict, weights.omega,
                                             weights.alpha, 3, 4)
    assert run.q_max == pytest.approx(q_max, abs=1e-3)
    assert run.q_mean == pytest.approx(q_mean, abs=1e-3)
    assert run.seconds > 0


def test_the_clock_on_cuda_reads_device_stages_from_events(monkeypatch):
    """The CUDA bookkeeping with stand-in events (no GPU here): device stages take the
    events' elapsed time, host stages their own, idle is the wall time the device stages
    leave; events are read once, at the end."""
    import time as _time

    class FakeEvent:
        def __init__(self, enable_timing: bool = False) -> None:
            assert enable_timing
            self.t: float | None = None

        def record(self) -> None:
            self.t = _time.perf_counter()

        def elapsed_time(self, end: FakeEvent) -> float:
            return (end.t - self.t) * 1e3

    syncs = []
    monkeypatch.setattr(torch.cuda, "Event", FakeEvent)
    monkeypatch.setattr(torch.cuda, "synchronize", lambda device=None: syncs.append(1))
    clock = StageClock("cuda")
    clock.start()
    with clock.stage("backbone"):
        _time.sleep(0.05)
    with clock.stage("copy"):
        _time.sleep(0.01)
    clock.add("decode", 0.5)  # in a thread: overlapped, not on the GPU's path
    with clock.stage("wait"):  # a host stage even on CUDA
        _time.sleep(0.02)
    _time.sleep(0.03)
    clock.stop()
    n_syncs = len(syncs)
    s = clock.seconds()
    assert len(syncs) == n_syncs + 1  # one synchronisation to read every event
    assert s["backbone"] == pytest.approx(0.05, abs=0.02)
    assert s["copy"] == pytest.approx(0.01, abs=0.01)
    assert s["decode"] == 0.5 and s["wait"] == pytest.approx(0.02, abs=0.015)
    assert s["idle"] == pytest.approx(s["wall"] - s["backbone"] - s["copy"], abs=1e-9)
    assert s["idle"] >= 0.04  # the wait and the last sleep: the GPU did nothing then
