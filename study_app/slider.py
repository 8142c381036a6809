"""Geometry and state of the continuous rating slider (no drawing here).

The track runs from ``x0`` to ``x1`` pixels and maps linearly to the scale ``vmin..vmax``.
There is no marker until the participant first clicks the track or presses an arrow key
(avoids anchoring); the first key press puts the marker at the middle of the scale.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field


@dataclass
class Slider:
    """A horizontal slider; ``value`` is None until first touched."""

    x0: float
    x1: float
    y: float
    vmin: float = 0.0
    vmax: float = 100.0
    labels: Sequence[tuple[float, str]] = ()
    grab_half_height: float = 24.0
    fine_step: float = 1.0
    coarse_step: float = 10.0
    value: float | None = None
    first_touch: float | None = None
    dragging: bool = False
    _touches: list[float] = field(default_factory=list, repr=False)

    def __post_init__(self) -> None:
        if not self.x1 > self.x0:
            raise ValueError("slider track must have positive length (x1 > x0)")
        if not self.vmax > self.vmin:
            raise ValueError("slider scale must have vmax > vmin")

    @property
    def is_set(self) -> bool:
        return self.value is not None

    def clamp(self, value: float) -> float:
        return min(self.vmax, max(self.vmin, value))

    def value_at(self, x: float) -> float:
        """Scale value under pixel column ``x`` (clamped to the scale)."""
        frac = (x - self.x0) / (self.x1 - self.x0)
        return self.clamp(self.vmin + frac * (self.vmax - self.vmin))

    def x_of(self, value: float) -> float:
        """Pixel column of a scale value."""
        frac = (self.clamp(value) - self.vmin) / (self.vmax - self.vmin)
        return self.x0 + frac * (self.x1 - self.x0)

    def label_positions(self) -> list[tuple[float, str]]:
        """(pixel column, text) of each scale label."""
        return [(self.x_of(pos), text) for pos, text in self.labels]

    def hit(self, x: float, y: float) -> bool:
        """True when a click at (x, y) grabs the slider (track plus a margin)."""
        return (self.x0 - self.grab_half_height <= x <= self.x1 + self.grab_half_height
                and abs(y - self.y) <= self.grab_half_height)

    def _touch(self, now: float) -> None:
        if self.first_touch is None:
            self.first_touch = now

    def press(self, x: float, y: float, now: float) -> bool:
        """Mouse button down; returns True when it landed on the slider."""
        if not self.hit(x, y):
            return False
        self._touch(now)
        self.dragging = True
        self.value = self.value_at(x)
        return True

    def drag(self, x: float) -> None:
        if self.dragging:
            self.value = self.value_at(x)

    def release(self) -> None:
        self.dragging = False

    def key_step(self, direction: int, coarse: bool, now: float) -> None:
        """Arrow key: first press sets the middle, later presses move by a fine/coarse step."""
        self._touch(now)
        if self.value is None:
            self.value = (self.vmin + self.vmax) / 2.0
            return
        step = self.coarse_step if coarse else self.fine_step
        self.value = self.clamp(self.value + direction * step)
