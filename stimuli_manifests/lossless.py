"""The lossless codecs stimuli are written with, and what each is good for.

Every codec here stores 8-bit RGB exactly (decoding returns the frames that were written), so
a stimulus written with any of them is what the participant sees and what a metric scores.
They differ in file size and in decode speed, which is what matters to the player: it decodes
a whole test/reference pair while the participant rates the previous one
(``benchmarks/bench_decode.py`` measures them; the documentation quotes the figures).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

LosslessCodec = Literal["ffv1", "x264rgb", "utvideo"]


@dataclass(frozen=True)
class CodecSpec:
    """How one lossless codec is written: container, file suffix, encoder and options."""

    name: LosslessCodec
    container: str
    suffix: str
    encoder: str
    pix_fmt: str
    options: dict[str, str] = field(default_factory=dict)
    summary: str = ""


LOSSLESS_CODECS: dict[str, CodecSpec] = {
    spec.name: spec
    for spec in (
        CodecSpec("ffv1", "matroska", ".mkv", "ffv1", "bgr0", {"level": "3", "slicecrc": "0"},
                  "FFV1 in Matroska: compact, archival; the slowest to decode"),
        CodecSpec("x264rgb", "matroska", ".mkv", "libx264rgb", "rgb24",
                  {"qp": "0", "preset": "medium"},
                  "x264 RGB at qp 0 in Matroska: the most widely playable; slow to decode"),
        CodecSpec("utvideo", "avi", ".avi", "utvideo", "gbrp", {"pred": "median"},
                  "UT Video in AVI: larger files, several times faster to decode (player-ready)"),
    )
}
# What `cgvq-study init --transcode` writes unless told otherwise: the fastest to decode.
PLAYER_CODEC: LosslessCodec = "utvideo"
# Codecs whose decoded frames can be trusted as the stimulus itself (the lossless ones above
# and other intra-frame lossless formats a researcher may bring).
LOSSLESS_DECODER_NAMES = frozenset({"ffv1", "libx264rgb", "rawvideo", "png", "utvideo",
                                    "ffvhuff", "huffyuv", "qtrle", "magicyuv"})


def codec_spec(name: str) -> CodecSpec:
    """The spec of a lossless codec by name; ``KeyError`` lists the known ones."""
    try:
        return LOSSLESS_CODECS[name]
    except KeyError:
        raise KeyError(f"unknown lossless codec {name!r}; use one of "
                       f"{', '.join(LOSSLESS_CODECS)}") from None
