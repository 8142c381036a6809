"""Make a synthetic study folder: render every scene, apply every family, write the manifest.

All frames of a scene share one 60 fps timeline (frame i is at i/60 s): the base-rate
reference is every (60/fps)-th frame of it, and the frame-interpolation family keeps the
frames of its lower rate and blends the rest, so its rendered frames are exactly the
reference's. Everything random is derived from the seed, and the renderer, the filters and
the lossless writer are deterministic, so the same options give the same bytes.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import shutil
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from session_store.errors import StudyError
from stimuli_manifests import (
    Condition,
    DisplayRequirements,
    Manifest,
    Reference,
    fill_checksums,
    load_manifest,
    save_manifest,
    src_id,
    write_video,
)

from ..preflight import available_memory_bytes
from .color import to_display
from .denoise import atrous_denoise
from .interpolate import interpolate_frames
from .methods import DEFAULT_SCENES, INTERPOLATED_FPS, METHODS
from .renderer import (
    GBuffer,
    SceneRenderer,
    available_scenes,
    create_context,
    max_render_size,
)
from .splats import splat_sequence
from .upscale import TemporalUpscaler, jitter_sequence
from .vrs import vrs_sequence

log = logging.getLogger(__name__)

VIDEO_DIR = "videos"
MANIFEST_NAME = "manifest.json"
PARTIAL_DIR = ".synth-partial"
"""Where a run renders before it moves the finished study into place (removed on failure)."""
MIN_SIZE = 16
MAX_SIZE = 8192
"""Frame sizes in pixels: the renderer's eight float32 attachments and the study's screens."""
MAX_SECONDS = 60.0
SPLAT_KEYFRAME_SECONDS = 0.25


@dataclass(frozen=True)
class SynthOptions:
    """What to make. Sizes in pixels; ``fps`` is the rate of every family but frame
    interpolation, which is always shown at 60 fps."""

    width: int = 128
    height: int = 128
    seconds: float = 1.0
    fps: int = 30
    scenes: tuple[str, ...] = DEFAULT_SCENES
    methods: tuple[str, ...] = tuple(METHODS)
    seed: int = 0
    study_id: str | None = None
    """None: ``synthetic-cg-`` and a digest of the options above, so that two synthetic
    studies of other videos never share an id (the analysis tells studies apart by it),
    while the same options, which render the same videos, give the same one."""

    def resolved_study_id(self) -> str:
        if self.study_id is not None:
            return self.study_id
        what = json.dumps([self.width, self.height, self.seconds, self.fps, list(self.scenes),
                           list(self.methods), self.seed])
        return f"synthetic-cg-{hashlib.sha256(what.encode()).hexdigest()[:8]}"

    def check(self) -> None:
        """Raise StudyError for options that cannot work, saying what to change."""
        if (not MIN_SIZE <= self.width <= MAX_SIZE or not MIN_SIZE <= self.height <= MAX_SIZE
                or self.width % 8 or self.height % 8):
            raise StudyError(
                f"--size {self.width}x{self.height}: width and height must be multiples of 8, "
                f"at least {MIN_SIZE} and at most {MAX_SIZE}"
            )
        if self.fps not in (30, 60):
            raise StudyError(f"--fps {self.fps}: choose 30 or 60")
        if not math.isfinite(self.seconds):
            raise StudyError(f"--seconds {self.seconds}: give a finite number of seconds, e.g. 1")
        if self.seconds > MAX_SECONDS:
            raise StudyError(f"--seconds {self.seconds:g} is too long for a rating stimulus: "
                             f"give at most {MAX_SECONDS:g} seconds")
        frames = self.seconds * self.fps
        if self.seconds <= 0 or abs(frames - round(frames)) > 1e-6 or round(frames) < 2:
            raise StudyError(
                f"--seconds {self.seconds} at {self.fps} fps must give a whole number of "
                "frames, at least 2"
            )
        if not self.scenes:
            raise StudyError("no scenes selected; give --scenes, e.g. "
                             f"--scenes {','.join(DEFAULT_SCENES)}")
        repeated = sorted({s for s in self.scenes if self.scenes.count(s) > 1})
        if repeated:
            raise StudyError(f"--scenes names {', '.join(repeated)} more than once; give each "
                             "scene once")
        unknown = [s for s in self.scenes if s not in available_scenes()]
        if unknown:
            raise StudyError(
                f"unknown scene(s) {', '.join(unknown)}; available: "
                f"{', '.join(available_scenes())}"
            )
        if not self.methods:
            raise StudyError(f"no methods selected; give --methods all or some of "
                             f"{', '.join(METHODS)}")
        bad = [m for m in self.methods if m not in METHODS]
        if bad:
            raise StudyError(
                f"unknown method(s) {', '.join(bad)}; choose from {', '.join(METHODS)}"
            )

    def memory_estimate(self) -> int:
        """Bytes of float frames held for one scene (everything of a scene stays in memory)."""
        pixel = self.width * self.height * 4
        base = self.frames_60 // self.base_step
        per_base = 0
        if {"path_tracing", "denoising"} & set(self.methods):
            per_base += 3 * 7  # six Monte Carlo estimates and the albedo
        if {"denoising", "splatting"} & set(self.methods):
            per_base += 13  # the G-buffer
        return pixel * (3 * _frames_to_render(self) + per_base * base)

    @property
    def frames_60(self) -> int:
        return round(self.seconds * INTERPOLATED_FPS)

    @property
    def base_step(self) -> int:
        return INTERPOLATED_FPS // self.fps


@dataclass
class _SceneFrames:
    """Everything rendered for one scene (linear float32 frames)."""

    ref60: list[np.ndarray] = field(default_factory=list)  # 60 fps timeline (+ extra frames)
    noisy: dict[int, list[np.ndarray]] = field(default_factory=dict)  # spp -> base frames
    albedo: list[np.ndarray] = field(default_factory=list)  # base frames, sample-averaged
    gbuf: list[GBuffer] = field(default_factory=list)  # base frames, full resolution


def _seed_for(seed: int, *parts: int) -> int:
    return int(np.random.SeedSequence([seed, *parts]).generate_state(1)[0])


def _interp_steps(opts: SynthOptions) -> list[int]:
    if "frame_interpolation" not in opts.methods:
        return []
    return [INTERPOLATED_FPS // int(lv.value) for lv in METHODS["frame_interpolation"].levels]


def _frames_to_render(opts: SynthOptions) -> int:
    """60 fps frames to render: the clip, plus the keyframe after it for interpolation."""
    n = opts.frames_60
    return max([n] + [((n - 1 + step - 1) // step) * step + 1 for step in _interp_steps(opts)])


def _render_scene(ctx, opts: SynthOptions, scene: str, scene_seed: int,
                  tick: Callable[[], None]) -> _SceneFrames:
    want_mc = bool({"path_tracing", "denoising"} & set(opts.methods))
    want_gbuf = bool({"denoising", "splatting"} & set(opts.methods))
    renderer = SceneRenderer(ctx, scene, opts.width, opts.height, seed=scene_seed)
    frames = _SceneFrames()
    dt = opts.base_step / INTERPOLATED_FPS
    try:
        for i in range(_frames_to_render(opts)):
            t = i / INTERPOLATED_FPS
            is_base = i % opts.base_step == 0 and i < opts.frames_60
            sampled = renderer.reference(t, i, mc=want_mc and is_base)
            frames.ref60.append(sampled.reference)
            for spp, img in sampled.noisy.items():
                frames.noisy.setdefault(spp, []).append(img)
            if sampled.albedo is not None:
                frames.albedo.append(sampled.albedo)
            if want_gbuf and is_base:
                frames.gbuf.append(renderer.gbuffer(t, t - dt, i))
            tick()
    finally:
        renderer.release()
    return frames


def _upscaled(ctx, opts: SynthOptions, scene: str, scene_seed: int,
              divisor: float) -> list[np.ndarray]:
    w = max(8, round(opts.width / divisor))
    h = max(8, round(opts.height / divisor))
    renderer = SceneRenderer(ctx, scene, w, h, seed=scene_seed)
    upscaler = TemporalUpscaler(opts.width, opts.height)
    dt = opts.base_step / INTERPOLATED_FPS
    n = opts.frames_60 // opts.base_step
    out = []
    try:
        for k, jitter in enumerate(jitter_sequence(n)):
            i = k * opts.base_step
            t = i / INTERPOLATED_FPS
            g = renderer.gbuffer(t, t - dt, i, jitter=jitter)
            out.append(upscaler.step(g.colour, g.motion, jitter))
    finally:
        renderer.release()
    return out


def _condition_frames(ctx, opts: SynthOptions, scene: str, scene_index: int, scene_seed: int,
                      frames: _SceneFrames, method: str,
                      value: float) -> tuple[list[np.ndarray], int]:
    """Linear frames of one condition and the frame rate it is shown at."""
    base = frames.ref60[0 : opts.frames_60 : opts.base_step]
    if method == "path_tracing":
        return frames.noisy[int(value)], opts.fps
    if method == "denoising":
        g = frames.gbuf
        out = atrous_denoise(np.stack(frames.noisy[int(value)]), np.stack(frames.albedo),
                             np.stack([b.normal for b in g]), np.stack([b.depth for b in g]),
                             np.stack([b.hit for b in g]))
        return list(out), opts.fps
    if method == "upscaling":
        return _upscaled(ctx, opts, scene, scene_seed, value), opts.fps
    if method == "splatting":
        n_splats = max(4, round(opts.width * opts.height / value))
        rng = np.random.default_rng(_seed_for(opts.seed, scene_index, 4, int(value)))
        interval = max(1, round(opts.fps * SPLAT_KEYFRAME_SECONDS))
        motions = [g.motion for g in frames.gbuf]
        return splat_sequence(base, motions, n_splats, interval, rng), opts.fps
    if method == "frame_interpolation":
        step = INTERPOLATED_FPS // int(value)
        return interpolate_frames(frames.ref60, step, opts.frames_60), INTERPOLATED_FPS
    if method == "vrs":
        return vrs_sequence(base, value / 100.0), opts.fps
    raise StudyError(f"unknown method {method!r}")  # pragma: no cover - checked in options


def _write(path: Path, frames: list[np.ndarray], fps: int) -> None:
    write_video(path, (to_display(f) for f in frames), fps)


def synthesize(out_dir: str | Path, opts: SynthOptions, *, overwrite: bool = False,
               progress: bool = True) -> Path:
    """Render the stimuli of ``opts`` into the study folder ``out_dir``; returns the manifest.

    The folder gets ``manifest.json`` and ``videos/<scene>/*.mkv`` (FFV1, lossless). Options
    are checked (sizes, duration, memory, the GL driver's limits) before anything is created;
    the study is rendered into ``PARTIAL_DIR`` inside ``out_dir`` and moved into place only when
    it is complete, so a failure leaves no half-made study (and keeps one being overwritten).
    """
    opts.check()
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise StudyError(f"--out {out} is a file; give a folder for the study")
    manifest_path = out / MANIFEST_NAME
    video_root = out / VIDEO_DIR
    if (manifest_path.exists() or video_root.exists()) and not overwrite:
        raise StudyError(
            f"{out} already holds a study ({MANIFEST_NAME} or {VIDEO_DIR}/); choose another "
            "--out or pass --overwrite"
        )
    need = opts.memory_estimate()
    available = available_memory_bytes()
    if available is not None and need > available:
        raise StudyError(
            f"rendering would hold about {need / 1024**3:.1f} GiB of frames per scene but only "
            f"{available / 1024**3:.1f} GiB of memory is available; use a smaller --size or "
            "--seconds"
        )
    if need > 2 * 1024**3:
        log.warning("rendering holds about %.1f GiB of frames per scene; use a smaller --size "
                    "or --seconds if memory runs out", need / 1024**3)
    ctx = create_context()
    try:
        limit = max_render_size(ctx)
        if limit is not None and max(opts.width, opts.height) > limit:
            raise StudyError(
                f"--size {opts.width}x{opts.height}: this OpenGL driver renders at most "
                f"{limit}x{limit} pixels; choose a smaller --size"
            )
        created = [p for p in (out, *out.parents) if not p.exists()]
        partial = out / PARTIAL_DIR
        shutil.rmtree(partial, ignore_errors=True)  # left by a run that was killed
        try:
            (partial / VIDEO_DIR).mkdir(parents=True)
            _build(ctx, opts, partial, progress)
        except BaseException:
            shutil.rmtree(partial, ignore_errors=True)
            for folder in created:  # deepest first; only the folders this run made
                try:
                    folder.rmdir()
                except OSError:
                    break
            raise
    finally:
        ctx.release()
    if overwrite:
        shutil.rmtree(video_root, ignore_errors=True)
        manifest_path.unlink(missing_ok=True)
    (partial / VIDEO_DIR).rename(video_root)
    (partial / MANIFEST_NAME).rename(manifest_path)
    partial.rmdir()
    log.info("wrote the study to %s", out)
    return manifest_path


def _build(ctx, opts: SynthOptions, folder: Path, progress: bool) -> None:
    """Render every scene and level into ``folder`` (``videos/`` and the manifest). A GL or
    memory failure becomes a StudyError that says what to change."""
    import moderngl

    try:
        _render_all(ctx, opts, folder, progress)
    except moderngl.Error as exc:
        raise StudyError(
            f"rendering {opts.width}x{opts.height} frames failed in the OpenGL driver "
            f"({' '.join(str(exc).split())}); choose a smaller --size"
        ) from None
    except MemoryError:
        raise StudyError(
            f"ran out of memory rendering {opts.width}x{opts.height} frames for "
            f"{opts.seconds:g} s; use a smaller --size or --seconds"
        ) from None


def _render_all(ctx, opts: SynthOptions, folder: Path, progress: bool) -> None:
    manifest_path = folder / MANIFEST_NAME
    video_root = folder / VIDEO_DIR
    conditions_per_scene = sum(len(METHODS[m].levels) for m in opts.methods)
    total = len(opts.scenes) * (_frames_to_render(opts) + conditions_per_scene)
    references: list[Reference] = []
    conditions: list[Condition] = []
    interp = "frame_interpolation" in opts.methods and opts.fps != INTERPOLATED_FPS
    with tqdm(total=total, desc="synth", unit="step", disable=not progress) as bar:
        for s_idx, scene in enumerate(opts.scenes):
            scene_seed = _seed_for(opts.seed, s_idx) & 0xFFFFFFFF
            bar.set_postfix_str(f"{scene}: rendering")
            frames = _render_scene(ctx, opts, scene, scene_seed, lambda: bar.update(1))
            base_ref = SceneRef(len(references) + 1, scene, opts.fps,
                                frames.ref60[0 : opts.frames_60 : opts.base_step])
            refs = {opts.fps: base_ref}
            if interp:
                refs[INTERPOLATED_FPS] = SceneRef(len(references) + 2, scene,
                                                  INTERPOLATED_FPS,
                                                  frames.ref60[: opts.frames_60])
            for ref in refs.values():
                rel = f"{scene}/reference_{ref.fps}fps.mkv"
                _write(video_root / rel, ref.frames, ref.fps)
                references.append(Reference(
                    id=ref.id, path=rel, scene=scene, fps=ref.fps, width=opts.width,
                    height=opts.height, frames=len(ref.frames),
                    metadata={"renderer": "16 jittered samples per pixel, expected lighting"},
                ))
            for method in opts.methods:
                for lv in METHODS[method].levels:
                    bar.set_postfix_str(f"{scene}: {method} L{lv.level}")
                    imgs, fps = _condition_frames(ctx, opts, scene, s_idx, scene_seed,
                                                  frames, method, lv.value)
                    rel = f"{scene}/{method}_L{lv.level}.mkv"
                    _write(video_root / rel, imgs, fps)
                    conditions.append(Condition(
                        reference=refs[fps].id, path=rel, method=method, level=lv.level,
                        setting=lv.setting,
                        metadata={"parameter": lv.value, "fps": fps, "scene": scene},
                    ))
                    bar.update(1)

    manifest = Manifest(
        study_id=opts.resolved_study_id(),
        title="Synthetic computer-graphics stimuli",
        description=(
            "Procedural GLSL scenes rendered off-screen; references with 16 anti-aliasing "
            "samples per pixel and closed-form lighting; six distortion families at four "
            "levels each (level 1 = strongest distortion)."
        ),
        root=VIDEO_DIR,
        display=DisplayRequirements(
            min_width=max(640, opts.width), min_height=max(480, opts.height), min_refresh_hz=59.0
        ),
        references=references,
        conditions=conditions,
        metadata={
            "generator": "cgvq-study synth",
            "options": {k: list(v) if isinstance(v, tuple) else v
                        for k, v in asdict(opts).items()},
            "methods": {m: METHODS[m].description for m in opts.methods},
        },
    )
    save_manifest(manifest, manifest_path)
    loaded = load_manifest(manifest_path)
    save_manifest(fill_checksums(loaded, progress=progress), manifest_path)
    log.info("wrote %d references and %d conditions", len(references), len(conditions))


@dataclass
class SceneRef:
    """A reference video of a scene at one frame rate, before it enters the manifest."""

    index: int
    scene: str
    fps: int
    frames: list[np.ndarray]

    @property
    def id(self) -> str:
        return src_id(self.index)
