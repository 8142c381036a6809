"""Whether a test video can be shown against its reference: same size, frame rate and length.

The player switches between the two on one shared frame clock, so any difference breaks the
comparison; one home for the rule, used by ``cgvq-study check`` and ``cgvq-study init``.
"""

from __future__ import annotations

from .video import VideoInfo

FPS_TOLERANCE = 1e-3  # in frames per second: 29.97 (30000/1001) is not 30


def same_frame_rate(a: float, b: float) -> bool:
    """Whether two frame rates are one (the player's and the metrics' one rule)."""
    return abs(a - b) <= FPS_TOLERANCE


def pair_mismatches(test_id: str, reference_id: str, test: VideoInfo, reference: VideoInfo
                    ) -> list[str]:
    """Every way ``test`` differs from its reference (empty when they match)."""
    out = []
    if (test.width, test.height) != (reference.width, reference.height):
        out.append(f"{test_id}: size {test.width}x{test.height} differs from its reference "
                   f"{reference_id} ({reference.width}x{reference.height}); re-render or "
                   "re-encode it at the reference's size")
    if not same_frame_rate(test.fps, reference.fps):
        out.append(f"{test_id}: {test.fps:g} fps differs from its reference {reference_id} "
                   f"({reference.fps:g} fps); re-render or re-encode it at the reference's "
                   "frame rate")
    if test.frame_count != reference.frame_count:
        out.append(f"{test_id}: {test.frame_count} frames, its reference {reference_id} has "
                   f"{reference.frame_count}; both loops must match")
    return out
