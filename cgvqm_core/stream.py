"""Streaming the videos through the metric clip by clip, in upstream's geometry.

The test video is aligned to the reference as the authors' code does it (bilinear resize of
uint8 frames to the reference's size, nearest-neighbour resampling in time to its frame
count), but frame by frame. Clips of ``int(min(fps, 30))`` frames are padded at the end of T,
H and W by replicating the last frame / row / column, cut into a grid of patches of
``(int(H/s), int(W/s))`` pixels, and each patch is scored on its own. Peak memory depends on
one clip, never on the video's length.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import torch
import torch.nn.functional as F
from tqdm.auto import tqdm

from stimuli_manifests import StimuliError, open_video
from stimuli_manifests.pairs import same_frame_rate

from .clip_feed import ClipSet, clip_sets
from .errors import CGVQMError
from .features import FeatureNet
from .host_memory import retained
from .patch_scorer import PatchScorer
from .seamless import network_halo, tile
from .stage_clock import StageClock, stage

log = logging.getLogger(__name__)

VideoInput = str | Path | np.ndarray | torch.Tensor
DEFAULT_ARRAY_FPS = 30.0


class FrameSource(Protocol):
    """Anything with ``info`` (width, height, fps, frame_count, path) and ``frames()``."""

    info: Any

    def frames(self) -> Iterator[np.ndarray]: ...


@dataclass(frozen=True)
class ArrayInfo:
    path: str
    width: int
    height: int
    fps: float
    frame_count: int


class ArraySource:
    """An in-memory (T, H, W, 3) uint8 video."""

    def __init__(self, array: np.ndarray | torch.Tensor, fps: float, name: str) -> None:
        arr = array.detach().cpu().numpy() if isinstance(array, torch.Tensor) else np.asarray(array)
        if arr.ndim != 4 or arr.shape[-1] != 3 or arr.dtype != np.uint8:
            raise CGVQMError(f"{name}: an array video must be (frames, height, width, 3) uint8, "
                             f"got shape {arr.shape} and dtype {arr.dtype}")
        if arr.shape[0] == 0:
            raise CGVQMError(f"{name}: the video has no frames")
        self.array = arr
        self.info = ArrayInfo(name, arr.shape[2], arr.shape[1], float(fps), arr.shape[0])

    def frames(self) -> Iterator[np.ndarray]:
        yield from self.array


def open_input(video: VideoInput | FrameSource, *, fps: float | None = None, name: str = "video",
               on_conversion: str = "warn", array_fps: float | None = None) -> FrameSource:
    """A streamable source for a path (video file, PNG folder, .npy), array or tensor.

    ``fps`` sets the rate of PNG folders and .npy files (which carry none; video files keep
    their own); in-memory
    arrays take ``array_fps`` (the reference's), else ``fps``, else 30.
    """
    check_rate(fps)
    if isinstance(video, np.ndarray | torch.Tensor):
        return ArraySource(video, array_fps or fps or DEFAULT_ARRAY_FPS, name)
    if isinstance(video, str | Path):
        path = Path(video)
        rate = fps if (path.is_dir() or path.suffix.lower() == ".npy") else None
        try:
            src = open_video(path, fps=rate, on_conversion=on_conversion)  # type: ignore[arg-type]
        except StimuliError as exc:
            raise CGVQMError(str(exc)) from None
        if src.info.kind == "frames":
            _check_png_depth(src, on_conversion)
        return src
    if hasattr(video, "info") and hasattr(video, "frames"):
        return video
    raise CGVQMError(f"{name}: unsupported video input of type {type(video).__name__}")


def check_rate(fps: float | None, what: str = "fps") -> None:
    """Refuse a frame rate that is not a finite number above 0: an infinite one would pass
    as clips of 30 frames and a silently wrong time axis, never as an error."""
    if fps is None:
        return
    try:
        ok = math.isfinite(float(fps)) and float(fps) > 0
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise CGVQMError(f"{what} must be a finite frame rate above 0 (frames per second of "
                         f"PNG folders and .npy arrays), got {fps!r}")


def png_bit_depth(path: Path) -> int | None:
    """Bits per sample from a PNG's header (PIL reports 16-bit RGB as 8-bit 'RGB')."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(26)
    except OSError:
        return None
    if len(head) < 26 or head[:8] != b"\x89PNG\r\n\x1a\n" or head[12:16] != b"IHDR":
        return None
    return head[24]


def _check_png_depth(src: Any, on_conversion: str) -> None:
    files = getattr(src, "_frame_files", None) or []
    depth = png_bit_depth(files[0]) if files else None
    if depth is None or depth <= 8 or src.info.bit_depth > 8:
        return
    msg = (f"{src.info.path}: {depth}-bit PNG frames are read as 8-bit RGB (the low byte of "
           "every sample is dropped)")
    if on_conversion == "error":
        raise CGVQMError(f"{msg}; convert them to 8-bit first or allow conversion "
                         "(--allow-convert)")
    log.warning("%s", msg)


@dataclass(frozen=True)
class Geometry:
    """How a reference-sized video is cut: clips x rows x columns of patches."""

    frames: int
    height: int
    width: int
    fps: float
    patch_scale: int = 4

    @property
    def clip_len(self) -> int:
        return int(min(self.fps, 30))

    @property
    def patch_h(self) -> int:
        return int(self.height / self.patch_scale)

    @property
    def patch_w(self) -> int:
        return int(self.width / self.patch_scale)

    @property
    def n_clips(self) -> int:
        return math.ceil(self.frames / self.clip_len)

    @property
    def n_rows(self) -> int:
        return math.ceil(self.height / self.patch_h)

    @property
    def n_cols(self) -> int:
        return math.ceil(self.width / self.patch_w)

    @property
    def n_patches(self) -> int:
        return self.n_clips * self.n_rows * self.n_cols

    def check(self, name: str) -> None:
        if self.clip_len < 1:
            raise CGVQMError(f"{name}: frame rate {self.fps} gives clips of 0 frames; CGVQM "
                             "needs at least 1 fps (pass the right fps for frame folders/arrays)")
        if self.patch_h < 1 or self.patch_w < 1:
            raise CGVQMError(f"{name}: {self.width}x{self.height} is too small for a patch "
                             f"grid of scale {self.patch_scale}")


def _counted(src: FrameSource, name: str) -> Iterator[np.ndarray]:
    """Frames of a source, refusing a decoded count other than the probed one."""
    n = 0
    try:
        for frame in src.frames():
            if n == src.info.frame_count:
                break
            n += 1
            yield frame
    except StimuliError as exc:
        raise CGVQMError(str(exc)) from None
    if n != src.info.frame_count:
        raise CGVQMError(f"{name}: {src.info.path} decoded {n} frames but its header promises "
                         f"{src.info.frame_count}; remux or re-encode it")


def time_index(n_src: int, n_dst: int) -> np.ndarray:
    """Which source frame each of ``n_dst`` frames takes under torch's 'nearest' resampling."""
    src = torch.arange(n_src, dtype=torch.float32).view(1, 1, n_src, 1, 1)
    return F.interpolate(src, size=(n_dst, 1, 1), mode="nearest").view(-1).long().numpy()


def resize_frame(frame: np.ndarray, height: int, width: int) -> np.ndarray:
    """Bilinear resize of a uint8 frame exactly as torch does it on uint8 (T, C, H, W)."""
    t = torch.from_numpy(np.ascontiguousarray(frame)).permute(2, 0, 1)[None].contiguous()
    out = F.interpolate(t, size=(height, width), mode="bilinear")
    return out[0].permute(1, 2, 0).contiguous().numpy()


def resampling_note(n_test: int, n_ref: int) -> str:
    """What resampling ``n_test`` frames to ``n_ref`` does, counted from the very index
    :func:`aligned_frames` uses: how many frames are invented (repeats) or dropped."""
    idx = time_index(n_test, n_ref)
    used = len(np.unique(idx))
    invented, dropped = n_ref - used, n_test - used
    what = []
    if invented:
        what.append(f"{invented} frame{'s were' if invented != 1 else ' was'} invented by "
                    "repeating test frames")
    if dropped:
        what.append(f"{dropped} test frame{'s were' if dropped != 1 else ' was'} dropped")
    shifted = int((idx != np.arange(n_ref)).sum())
    shift = (f"; {shifted} of the {n_ref} reference frames are compared with a test frame "
             "from another moment (a test with extra frames at its end: trim it to the "
             "reference's length)" if shifted else "")
    return (f"test has {n_test} frames, reference {n_ref}: {' and '.join(what)} "
            "(nearest-neighbour resampling in time to the reference's frame count, as "
            f"upstream; no interpolation){shift}; --strict refuses such a pair")


def alignment_note(ref: FrameSource, test: FrameSource) -> str:
    """How the test is fitted to the reference before scoring ("" when it is not): the score
    of a resized or resampled test is not the score of the file as rendered, and its row in a
    scores CSV says so (``note``)."""
    r, t = ref.info, test.info
    parts = []
    if not same_frame_rate(float(r.fps), float(t.fps)):
        parts.append(f"test at {float(t.fps):g} fps, reference at {float(r.fps):g} fps")
    if (int(t.height), int(t.width)) != (int(r.height), int(r.width)):
        parts.append(f"test resized from {t.width}x{t.height} to the reference's "
                     f"{r.width}x{r.height} (bilinear)")
    nt, nr = int(t.frame_count), int(r.frame_count)
    if nt != nr:
        used = len(np.unique(time_index(nt, nr)))
        parts.append(f"test's {nt} frames resampled in time to the reference's {nr} "
                     f"({nr - used} repeated, {nt - used} dropped)")
    return "; ".join(parts)


def frame_count_mismatch(ref: FrameSource, test: FrameSource) -> str | None:
    """Why ``test`` cannot be compared frame for frame with ``ref``, or None if it can."""
    nr, nt = int(ref.info.frame_count), int(test.info.frame_count)
    if nr == nt:
        return None
    return (f"{test.info.path}: test has {nt} frames, reference {nr} ({ref.info.path})")


def check_frame_count(ref: FrameSource, test: FrameSource, strict: bool) -> None:
    """With ``strict``, a test whose frame count differs from the reference's is an error
    (otherwise :func:`aligned_frames` resamples it in time and says how)."""
    why = frame_count_mismatch(ref, test) if strict else None
    if why is not None:
        raise CGVQMError(f"{why}; --strict (strict=True) refuses a frame-count mismatch "
                         "instead of resampling the test in time (repeating or dropping "
                         "frames); trim or re-render one of them")


def aligned_frames(test: FrameSource, geom: Geometry, name: str = "test") -> Iterator[np.ndarray]:
    """The test video's frames resized and resampled in time to the reference's geometry."""
    info = test.info
    resize = (info.height, info.width) != (geom.height, geom.width)
    idx = time_index(info.frame_count, geom.frames) if info.frame_count != geom.frames else None
    if resize:
        log.warning("%s: resizing %dx%d to the reference's %dx%d (bilinear, as upstream)",
                    info.path, info.width, info.height, geom.width, geom.height)
    if idx is not None:
        log.warning("%s: %s", info.path, resampling_note(int(info.frame_count), geom.frames))
    frames = _counted(test, name)
    if idx is None:
        for f in frames:
            yield resize_frame(f, geom.height, geom.width) if resize else f
        return
    pos, cur = -1, None
    for j in idx:
        while pos < j:
            cur = next(frames)
            pos += 1
            if resize:
                cur = resize_frame(cur, geom.height, geom.width)
        yield cur  # type: ignore[misc]
    for _ in frames:  # drain so the count check runs
        pass


def padded_clips(frames: Iterator[np.ndarray], geom: Geometry) -> Iterator[tuple[np.ndarray, int]]:
    """(clip, valid frames): clips of clip_len frames padded by replication to the patch grid.

    One buffer is reused for every clip (memory): a consumer must be done with a clip before
    asking for the next one, or copy it.
    """
    L = geom.clip_len
    Hp, Wp = geom.n_rows * geom.patch_h, geom.n_cols * geom.patch_w
    buf = np.empty((L, Hp, Wp, 3), dtype=np.uint8)
    n = 0
    for f in frames:
        buf[n, : geom.height, : geom.width] = f
        if Hp > geom.height:
            buf[n, geom.height:, : geom.width] = f[-1:, :, :]
        if Wp > geom.width:
            buf[n, :, geom.width:] = buf[n, :, geom.width - 1: geom.width]
        n += 1
        if n == L:
            yield buf, L
            n = 0
    if n:
        buf[n:] = buf[n - 1]
        yield buf, n


@dataclass
class StreamOutput:
    """Per test video: the channel MSD of every patch and, with weights, per-frame errors."""

    geometry: Geometry
    msd: np.ndarray  # (n_patches, N) float32, patches in clip, row, column order
    series: np.ndarray | None  # (n_clips, n_rows, n_cols, clip_len) per-frame patch errors

    @property
    def patch_index(self) -> np.ndarray:
        """(n_patches, 3): clip, row, column of every row of ``msd``."""
        g = self.geometry
        return np.stack(np.unravel_index(np.arange(g.n_patches), (g.n_clips, g.n_rows, g.n_cols)),
                        axis=1)


EmapSink = Callable[[int, np.ndarray, np.ndarray], None]
"""Called per clip with (clip index, error map (t, H, W) float32, test frames (t, H, W, 3))."""


def reference_geometry(ref: FrameSource, patch_scale: int) -> Geometry:
    info = ref.info
    g = Geometry(int(info.frame_count), int(info.height), int(info.width), float(info.fps),
                 int(patch_scale))
    g.check(str(info.path))
    return g


def check_fps(ref: FrameSource, test: FrameSource, allow_resample: bool) -> None:
    """An fps mismatch is an error unless resampling was allowed (then it is logged)."""
    if isinstance(test, ArraySource) or isinstance(ref, ArraySource):
        return
    fr, ft = float(ref.info.fps), float(test.info.fps)
    if not same_frame_rate(fr, ft):
        if not allow_resample:
            raise CGVQMError(
                f"{test.info.path}: {ft:g} fps differs from the reference's {fr:g} fps; pass "
                "--allow-resample (allow_resample=True) to resample it to the reference's frame "
                "count as the authors' code does"
            )
        log.warning("%s: %g fps resampled to the reference's %g fps by frame count",
                    test.info.path, ft, fr)


def run(ref: FrameSource, tests: Sequence[FrameSource], scorer: PatchScorer, geom: Geometry, *,
        emap_sinks: Sequence[EmapSink | None] | None = None, progress: bool = False,
        desc: str = "cgvqm", seamless: bool = False, prefetch: bool | None = None,
        clock: StageClock | None = None) -> list[StreamOutput]:
    """Score every patch of every test video against the reference, clip by clip.

    ``seamless`` runs each patch on a crop with a halo and keeps its core's features
    (:mod:`.seamless`; not upstream-identical). ``prefetch`` decodes the next clip in a
    thread while the current one is scored (:mod:`.clip_feed`; default: on CUDA only, where
    the network is fast enough for decoding to matter). On CUDA each clip is copied to the
    GPU once, patches are cut there, several patch positions go through the network
    together when the batch size allows, and results come back once per clip. ``clock``
    adds up the time of each stage (:mod:`.stage_clock`).
    """
    sinks = list(emap_sinks) if emap_sinks is not None else [None] * len(tests)
    want_emap = any(s is not None for s in sinks)
    halo = network_halo(scorer.net.model, scorer.net.n_levels) if seamless else None
    dev = scorer.net.device
    cuda = dev.type == "cuda"
    ref_clips = padded_clips(_counted(ref, "reference"), geom)
    test_clips = [padded_clips(aligned_frames(t, geom, f"test {i}"), geom)
                  for i, t in enumerate(tests)]
    ph, pw, L = geom.patch_h, geom.patch_w, geom.clip_len
    grid = [(r, c) for r in range(geom.n_rows) for c in range(geom.n_cols)]
    per_pass = (1 if halo is not None
                else scorer.positions_per_pass(len(tests), L * ph * pw))
    msd: list[list[torch.Tensor]] = [[] for _ in tests]
    series: list[list[torch.Tensor]] = [[] for _ in tests]
    bar = tqdm(total=geom.n_clips, desc=desc, unit="clip", disable=not progress, leave=False)
    feed = clip_sets(ref_clips, test_clips, prefetch=cuda if prefetch is None else prefetch,
                     pin=cuda, clock=clock)
    if clock is not None:
        clock.start()
    # on a CPU, freed activations are kept for the next pass (fresh pages cost 9 %)
    try:
        with retained(dev.type == "cpu"):
            for clip in feed:
                with stage(clock, "copy"):
                    rt = clip.ref.to(dev, non_blocking=True) if cuda else clip.ref
                    tts = [t.to(dev, non_blocking=True) if cuda else t for t in clip.tests]
                m, s, e = _score_clip(scorer, rt, tts, geom, grid, per_pass, halo, want_emap,
                                      clock)
                for i in range(len(tests)):
                    msd[i].append(m[:, i])
                    if s is not None:
                        series[i].append(s[:, i])
                if e is not None:
                    _send_emaps(e, clip, sinks, geom, grid)
                bar.update(1)
    finally:
        feed.close()
        if clock is not None:
            clock.stop()
        bar.close()
    outs_final = []
    for i in range(len(tests)):
        mi = torch.cat(msd[i]).numpy().astype(np.float32)
        si = None
        if series[i]:
            si = torch.cat(series[i]).numpy().reshape(geom.n_clips, geom.n_rows, geom.n_cols, L)
        outs_final.append(StreamOutput(geom, mi, si))
    return outs_final


def _send_emaps(e: torch.Tensor, clip: ClipSet, sinks: Sequence[EmapSink | None], geom: Geometry,
                grid: list[tuple[int, int]]) -> None:
    """One clip's error maps (per position, per test) assembled into frames for the sinks."""
    ph, pw, L = geom.patch_h, geom.patch_w, geom.clip_len
    emaps = np.zeros((len(sinks), L, geom.n_rows * ph, geom.n_cols * pw), np.float32)
    for p, (r, c) in enumerate(grid):
        emaps[:, :, r * ph:(r + 1) * ph, c * pw:(c + 1) * pw] = e[p].numpy()
    for i, sink in enumerate(sinks):
        if sink is not None:
            sink(clip.index, emaps[i, :clip.valid, : geom.height, : geom.width],
                 clip.tests[i].numpy()[:clip.valid, : geom.height, : geom.width])


def _score_clip(scorer: PatchScorer, rt: torch.Tensor, tts: list[torch.Tensor],
                geom: Geometry, grid: list[tuple[int, int]], per_pass: int, halo: Any,
                want_emap: bool, clock: StageClock | None
                ) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor | None]:
    """Every patch position of one clip, ``per_pass`` positions per network pass; the
    results come back to the host together: msd (positions, k, N), per-frame series
    (positions, k, T) and error maps (positions, k, T, h, w) when asked."""
    ph, pw = geom.patch_h, geom.patch_w
    outs = []
    for g0 in range(0, len(grid), per_pass):
        group = grid[g0: g0 + per_pass]
        cores = None
        if halo is None:
            sls = [(slice(None), slice(r * ph, (r + 1) * ph), slice(c * pw, (c + 1) * pw))
                   for r, c in group]
        else:
            tl = tile(*group[0], ph, pw, geom.height, geom.width, halo)
            sls, cores = [(slice(None), tl.crop_h, tl.crop_w)], tl.cores
        outs.append(scorer.compare([rt[sl] for sl in sls], [[t[sl] for t in tts] for sl in sls],
                                   emap=want_emap, cores=cores, clock=clock))
    with stage(clock, "pooling"):  # one transfer (and sync) per clip
        m = torch.cat([o.msd for o in outs]).cpu()
        s = torch.cat([o.series for o in outs]).cpu() if outs[0].series is not None else None
        e = torch.cat([o.emap for o in outs]).cpu() if want_emap else None
    scorer.check_finite(m)
    return m, s, e


def as_video_list(tests: VideoInput | Sequence[VideoInput]) -> list[VideoInput]:
    """``tests`` as a list of videos: one path, or one (T, H, W, 3) array or tensor, is one
    video (iterating it would take a path's characters or an array's frames for videos)."""
    if isinstance(tests, str | Path):
        return [tests]
    if isinstance(tests, np.ndarray | torch.Tensor) and tests.ndim != 5:
        return [tests]
    return list(tests)  # type: ignore[arg-type]


def patch_channel_msd(ref: VideoInput, tests: VideoInput | Sequence[VideoInput], net: FeatureNet,
                      *, patch_scale: int = 4, fps: float | None = None,
                      allow_resample: bool = False, batch_size: int | None = None,
                      on_conversion: str = "warn", progress: bool = False,
                      seamless: bool = False, strict: bool = False) -> list[StreamOutput]:
    """The per-patch, per-channel mean squared feature differences of test videos vs ``ref``.

    Returns one :class:`StreamOutput` per test video; ``.msd`` is (n_patches, N) with N = 131
    (CGVQM-2) or 1027 (CGVQM-5) columns in level order, ``.patch_index`` says which clip, row
    and column each row is. A CGVQM patch error is ``alpha * msd @ |omega|``. This is what a
    calibration caches: it does not depend on omega or alpha. ``strict`` refuses a test whose
    frame count differs from the reference's instead of resampling it.
    """
    if not isinstance(net, FeatureNet):
        raise CGVQMError(f"patch_channel_msd takes the metric's FeatureNet, not a "
                         f"{type(net).__name__}; with a CGVQM object call its channel_msd")
    test_list = as_video_list(tests)
    rsrc = open_input(ref, fps=fps, name="reference", on_conversion=on_conversion)
    geom = reference_geometry(rsrc, patch_scale)
    tsrcs = [open_input(t, fps=fps, name=f"test {i}", on_conversion=on_conversion,
                        array_fps=geom.fps) for i, t in enumerate(test_list)]
    for t in tsrcs:
        check_fps(rsrc, t, allow_resample)
        check_frame_count(rsrc, t, strict)
    scorer = PatchScorer(net, None, batch_size=batch_size)
    return run(rsrc, tsrcs, scorer, geom, progress=progress, seamless=seamless)
