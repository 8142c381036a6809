"""Settings of a running study server (the ``serve`` flags map onto these)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from session_store.protocol import CLOCK_SKEW_LIMIT_S, MAX_BODY_BYTES, OFFLINE_GAP_LIMIT_S

from .stopping import StoppingTarget


@dataclass
class ServerConfig:
    study: Path
    new_version: bool = False
    """Serve a changed manifest as a new version while sessions exist on the old one."""
    max_body_bytes: int = MAX_BODY_BYTES
    rate_per_s: float = 10.0
    """Requests per second per participant token, on average..."""
    burst: float = 60.0
    """...with bursts up to this many (a study download is one request per file)."""
    stats_every_s: float = 30.0
    """Recompute the dashboard's statistics at most this often."""
    target_raters: int | None = None
    """Raters wanted per stimulus (default: everyone invited)."""
    clock_skew_s: float = CLOCK_SKEW_LIMIT_S
    offline_gap_s: float = OFFLINE_GAP_LIMIT_S
    secure_cookies: bool = False
    """Mark the dashboard cookie Secure (set when serving over TLS or behind a TLS proxy)."""
    stats_in_background: bool = True
    store_addresses: bool = False
    """Keep each participant's last client address (``serve --keep-addresses``, to trace abuse
    with your own tools); off by default: an address is personal data that nothing here
    shows or uses, so keeping it would only add to what an ethics application must list."""
    stopping: StoppingTarget = field(default_factory=StoppingTarget)
    """The stopping rule's target (see :mod:`.stopping`); unset: none."""

    def __post_init__(self) -> None:
        self.study = Path(self.study)
