"""Off-screen rendering of the synthetic scenes with ModernGL (EGL, no window).

A scene is ``shaders/synth_common.glsl`` followed by ``shaders/synth_scene_<name>.glsl``.
Every pass draws one full-screen triangle into eight float32 colour attachments and reads
them back as (H, W, 3|4) arrays, row 0 at the top of the image. See the comment at the top
of ``synth_common.glsl`` for what each pass writes.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from importlib import resources

import numpy as np

from session_store.errors import StudyError
from shaders import shader_source

log = logging.getLogger(__name__)

N_ATTACHMENTS = 8
MC_SPP = (2, 4, 8, 16, 64, 256)
"""Samples per pixel of the Monte Carlo estimates written by pass 0 (attachments 1..6)."""
REFERENCE_AA = 16


def available_scenes() -> list[str]:
    """Names of the scene shaders shipped in ``shaders/`` (``synth_scene_<name>.glsl``)."""
    names = []
    for entry in resources.files("shaders").iterdir():
        name = entry.name
        if name.startswith("synth_scene_") and name.endswith(".glsl"):
            names.append(name.removeprefix("synth_scene_").removesuffix(".glsl"))
    return sorted(names)


def create_context():  # -> moderngl.Context
    """A standalone EGL OpenGL context, or a StudyError that says how to get one."""
    try:
        import moderngl
    except ImportError as exc:  # pragma: no cover - moderngl is a dependency
        raise StudyError(f"moderngl is not installed ({exc}); reinstall the toolkit") from None
    try:
        return moderngl.create_standalone_context(backend="egl", require=330)
    except Exception as exc:
        raise StudyError(
            f"cannot create an off-screen OpenGL 3.3 context through EGL ({exc}); install "
            "Mesa's EGL and GL drivers (e.g. apt-get install libegl1 libegl-mesa0 "
            "libgl1-mesa-dri)"
        ) from None


def max_render_size(ctx) -> int | None:
    """The largest width or height the context can render into (texture, renderbuffer and
    viewport limits), or None when the driver does not say."""
    limits = []
    for key in ("GL_MAX_TEXTURE_SIZE", "GL_MAX_RENDERBUFFER_SIZE", "GL_MAX_VIEWPORT_DIMS"):
        value = ctx.info.get(key)
        if isinstance(value, (tuple, list)):
            limits.extend(int(v) for v in value)
        elif isinstance(value, int):
            limits.append(value)
    return min(limits) if limits else None


@dataclass(frozen=True)
class SampledFrame:
    """Pass 0: the reference, Monte Carlo estimates by spp and the sample-averaged albedo."""

    reference: np.ndarray  # (H, W, 3) linear radiance
    noisy: dict[int, np.ndarray]  # spp -> (H, W, 3); empty unless requested
    albedo: np.ndarray | None  # (H, W, 3) when the Monte Carlo estimates were requested


@dataclass(frozen=True)
class GBuffer:
    """Pass 1 at one sample per pixel: expected colour and what post-processing needs."""

    colour: np.ndarray  # (H, W, 3) linear radiance
    motion: np.ndarray  # (H, W, 2) pixels, image axes: previous position minus current
    depth: np.ndarray  # (H, W)
    normal: np.ndarray  # (H, W, 3)
    albedo: np.ndarray  # (H, W, 3)
    hit: np.ndarray  # (H, W) bool: a surface (not sky or a light) was hit


class SceneRenderer:
    """Renders one scene at one resolution; reuse it for every frame of that size."""

    def __init__(self, ctx, scene: str, width: int, height: int, *, seed: int) -> None:
        if scene not in available_scenes():
            raise StudyError(
                f"unknown scene {scene!r}; available: {', '.join(available_scenes())}"
            )
        self.ctx = ctx
        self.scene = scene
        self.width, self.height = int(width), int(height)
        source = shader_source("synth_common.glsl") + "\n" + shader_source(
            f"synth_scene_{scene}.glsl"
        )
        try:
            self.program = ctx.program(
                vertex_shader=shader_source("synth_fullscreen.vert"), fragment_shader=source
            )
        except Exception as exc:
            raise StudyError(f"scene {scene!r}: shader does not compile: {exc}") from None
        self.vao = ctx.vertex_array(self.program, [])
        self.textures = []
        try:
            for _ in range(N_ATTACHMENTS):
                self.textures.append(ctx.texture((self.width, self.height), 4, dtype="f4"))
            self.fbo = ctx.framebuffer(color_attachments=self.textures)
        except Exception as exc:
            for tex in self.textures:
                tex.release()
            self.vao.release()
            self.program.release()
            raise StudyError(
                f"the OpenGL driver cannot render {self.width}x{self.height} frames "
                f"({' '.join(str(exc).split())}); choose a smaller --size"
            ) from None
        self._set("u_res", (float(self.width), float(self.height)))
        self._set("u_seed", int(seed) & 0xFFFFFFFF)

    def _set(self, name: str, value) -> None:
        if name in self.program:
            self.program[name].value = value

    def _draw(self, *, time: float, time_prev: float, frame: int, pass_: int, aa: int = 1,
              mc: bool = False, jitter: tuple[float, float] = (0.0, 0.0), outputs: int) -> list:
        self._set("u_time", float(time))
        self._set("u_time_prev", float(time_prev))
        self._set("u_frame", int(frame) & 0xFFFFFFFF)
        self._set("u_pass", int(pass_))
        self._set("u_aa", int(aa))
        self._set("u_mc", 1 if mc else 0)
        self._set("u_jitter", (float(jitter[0]), float(jitter[1])))
        self.fbo.use()
        self.ctx.viewport = (0, 0, self.width, self.height)
        self.vao.render(mode=self.ctx.TRIANGLES, vertices=3)
        out = []
        for i in range(outputs):
            raw = self.fbo.read(components=4, attachment=i, dtype="f4")
            arr = np.frombuffer(raw, dtype=np.float32).reshape(self.height, self.width, 4)
            out.append(arr[::-1].copy())
        return out

    def reference(self, time: float, frame: int, *, mc: bool) -> SampledFrame:
        """The 16-sample reference, plus the Monte Carlo estimates by spp when ``mc``."""
        bufs = self._draw(time=time, time_prev=time, frame=frame, pass_=0,
                          aa=REFERENCE_AA, mc=mc, outputs=N_ATTACHMENTS if mc else 1)
        noisy = {spp: bufs[1 + i][..., :3] for i, spp in enumerate(MC_SPP)} if mc else {}
        albedo = bufs[7][..., :3] if mc else None
        return SampledFrame(bufs[0][..., :3], noisy, albedo)

    def gbuffer(self, time: float, time_prev: float, frame: int,
                jitter: tuple[float, float] = (0.0, 0.0)) -> GBuffer:
        """One sample per pixel at the pixel centre plus ``jitter`` (image axes, pixels)."""
        c, m, n, a = self._draw(time=time, time_prev=time_prev, frame=frame, pass_=1,
                                jitter=(jitter[0], -jitter[1]), outputs=4)
        return GBuffer(colour=c[..., :3], motion=m[..., :2], depth=m[..., 2],
                       normal=n[..., :3], albedo=a[..., :3], hit=m[..., 3] > 0.5)

    def release(self) -> None:
        self.fbo.release()
        for tex in self.textures:
            tex.release()
        self.vao.release()
        self.program.release()
