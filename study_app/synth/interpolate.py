"""Frame interpolation: a low frame rate brought up to the display rate by blending.

Frames that fall on a rendered instant are the rendered frames themselves; the others are
cross-fades of the two rendered neighbours (ghosting, and judder in the motion).
"""

from __future__ import annotations

import numpy as np


def interpolate_frames(frames: list[np.ndarray], step: int, count: int) -> list[np.ndarray]:
    """``count`` output frames from full-rate ``frames`` of which only every ``step``-th
    is used; ``frames`` must reach the keyframe after the last output frame."""
    last_key = ((count - 1 + step - 1) // step) * step
    if len(frames) <= last_key:
        raise ValueError(f"need {last_key + 1} frames to interpolate {count}, got {len(frames)}")
    out = []
    for i in range(count):
        a = (i // step) * step
        w = (i - a) / step
        if w == 0.0:
            out.append(frames[a])
        else:
            out.append(((1.0 - w) * frames[a] + w * frames[a + step]).astype(np.float32))
    return out
