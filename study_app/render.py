"""Drawing with ModernGL: videos at 1:1 pixels, flat rectangles and text.

All coordinates are window pixels with the origin at the top left. Video frames live in one
2D texture per frame, uploaded before a trial starts so the presentation path only binds a
texture. A frame is a pixel-aligned quad of the frame's own size sampled with nearest
filtering at texel centres (exact 1:1 pixels on any conformant driver), drawn without
blending: the form Mesa's software rasteriser handles on its fast linear path (measured in
bench_player: CPU per refresh fell from 12-14 ms to ~8 ms against a texelFetch from an array).
"""

from __future__ import annotations

from dataclasses import dataclass

import moderngl
import numpy as np
import pygame

from shaders import shader_source

from .fonts import Fonts

Color = tuple[float, float, float, float]
MID_GREY: Color = (0.5, 0.5, 0.5, 1.0)
WHITE: Color = (1.0, 1.0, 1.0, 1.0)
BLACK: Color = (0.0, 0.0, 0.0, 1.0)


@dataclass
class VideoTexture:
    """A decoded video on the GPU: one texture per frame."""

    frames: list[moderngl.Texture]
    width: int
    height: int

    @property
    def frame_count(self) -> int:
        return len(self.frames)

    def release(self) -> None:
        for tex in self.frames:
            tex.release()
        self.frames = []


class Renderer:
    """The player's GL programs and a text cache."""

    def __init__(self, ctx: moderngl.Context, size: tuple[int, int],
                 fonts: Fonts | None = None) -> None:
        self.ctx = ctx
        self.fonts = fonts or Fonts()
        self.size = size
        vert = shader_source("player_quad.vert")
        self.solid = ctx.program(vertex_shader=vert,
                                 fragment_shader=shader_source("player_solid.frag"))
        self.video = ctx.program(vertex_shader=vert,
                                 fragment_shader=shader_source("player_video.frag"))
        self.text_prog = ctx.program(vertex_shader=vert,
                                     fragment_shader=shader_source("player_text.frag"))
        corners = np.array([0, 0, 1, 0, 0, 1, 1, 1], dtype="f4")
        self._vbo = ctx.buffer(corners.tobytes())
        self._vaos = {
            prog: ctx.vertex_array(prog, [(self._vbo, "2f", "in_corner")])
            for prog in (self.solid, self.video, self.text_prog)
        }
        for prog in self._vaos:
            prog["u_viewport"].value = size
        self.video["u_tex"].value = 0
        self.text_prog["u_tex"].value = 0
        self._text_cache: dict[tuple[str, int, str], tuple[moderngl.Texture, int, int]] = {}
        ctx.enable(moderngl.BLEND)
        ctx.blend_func = moderngl.SRC_ALPHA, moderngl.ONE_MINUS_SRC_ALPHA

    # -- primitives -------------------------------------------------------------------
    def clear(self, color: Color = MID_GREY) -> None:
        self.ctx.screen.use()
        self.ctx.clear(*color)

    def rect(self, x: float, y: float, w: float, h: float, color: Color) -> None:
        self.solid["u_rect"].value = (x, y, w, h)
        self.solid["u_color"].value = color
        self._vaos[self.solid].render(moderngl.TRIANGLE_STRIP)

    def upload_video(self, frames: np.ndarray) -> VideoTexture:
        """Upload (T, H, W, 3) uint8 frames, one texture each."""
        _, h, w, _ = frames.shape
        textures = []
        for frame in frames:
            tex = self.ctx.texture((w, h), 3, np.ascontiguousarray(frame), alignment=1)
            tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
            tex.repeat_x = tex.repeat_y = False
            textures.append(tex)
        return VideoTexture(textures, w, h)

    def draw_video(self, video: VideoTexture, frame: int, x: int | None = None,
                   y: int | None = None) -> tuple[int, int]:
        """Draw one frame at 1:1 pixels with its top-left at (x, y) (default: centred);
        returns its top-left corner."""
        cx, cy, w, h = self.video_rect(video.width, video.height)
        x = cx if x is None else x
        y = cy if y is None else y
        video.frames[frame].use(0)
        self.video["u_rect"].value = (x, y, w, h)
        self.ctx.disable(moderngl.BLEND)
        self._vaos[self.video].render(moderngl.TRIANGLE_STRIP)
        self.ctx.enable(moderngl.BLEND)
        return x, y

    def video_rect(self, width: int, height: int) -> tuple[int, int, int, int]:
        return ((self.size[0] - width) // 2, (self.size[1] - height) // 2, width, height)

    def frame(self, x: float, y: float, w: float, h: float, thickness: float,
              color: Color) -> None:
        """An outline drawn inside the rectangle (x, y, w, h)."""
        t = thickness
        self.rect(x, y, w, t, color)
        self.rect(x, y + h - t, w, t, color)
        self.rect(x, y + t, t, h - 2 * t, color)
        self.rect(x + w - t, y + t, t, h - 2 * t, color)

    # -- text -------------------------------------------------------------------------
    def text_size(self, text: str, px: int = 28, style: str = "regular") -> tuple[int, int]:
        return self.fonts.size(text, px, style)

    def text(self, text: str, x: float, y: float, *, px: int = 28, color: Color = WHITE,
             anchor: str = "topleft", style: str = "regular") -> tuple[int, int]:
        """Draw one line of text; ``anchor`` is topleft, center or topright. Returns its size."""
        if not text:
            return 0, 0
        key = (text, px, style)
        if key not in self._text_cache:
            surf = self.fonts.font(px, style).render(text, True, (255, 255, 255))
            data = pygame.image.tostring(surf, "RGBA", False)
            tex = self.ctx.texture(surf.get_size(), 4, data)
            tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
            if len(self._text_cache) > 1024:
                for old, _, _ in self._text_cache.values():
                    old.release()
                self._text_cache.clear()
            self._text_cache[key] = (tex, surf.get_width(), surf.get_height())
        tex, w, h = self._text_cache[key]
        if anchor == "center":
            x -= w / 2
        elif anchor == "topright":
            x -= w
        tex.use(0)
        self.text_prog["u_rect"].value = (round(x), round(y), w, h)
        self.text_prog["u_tint"].value = color
        self._vaos[self.text_prog].render(moderngl.TRIANGLE_STRIP)
        return w, h

    def read_pixels(self) -> np.ndarray:
        """The window's current back buffer as (H, W, 3) uint8, top row first."""
        data = self.ctx.screen.read(components=3, alignment=1)
        arr = np.frombuffer(data, dtype=np.uint8).reshape(self.size[1], self.size[0], 3)
        return arr[::-1].copy()
