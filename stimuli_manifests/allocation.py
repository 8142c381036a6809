"""How trials are allocated to participants: the ``protocol.allocation`` part of a manifest.

``full`` (the default, the paper's design): every participant rates every stimulus
``protocol.repetitions`` times. ``adaptive``: a session is ``blocks`` blocks; the first holds
every stimulus once (it keeps each rater's bias and inconsistency estimable on a complete
matrix, and gives screening and ICC a complete subset), the others are planned by the study
server from the ratings that have arrived, giving more trials to the stimuli whose DMOS
intervals are widest (see ``analysis.allocation``).
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

AllocationPolicy = Literal["full", "adaptive"]


class AdaptiveAllocation(BaseModel):
    """The settings of ``adaptive`` allocation."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True)

    blocks: int = Field(default=3, ge=2, le=20,
                        description="blocks per session; block 1 holds every stimulus once")
    block_trials: int | None = Field(
        default=None, ge=1, le=10_000,
        description="trials in each later block; default: the number of stimuli")
    max_per_block: int = Field(default=3, ge=1, le=10,
                               description="times one stimulus may appear in a later block")
    warmup_participants: int = Field(
        default=2, ge=2, le=100,
        description="sessions that must have finished block 1 before the server adapts; "
                    "blocks issued before then are uniform")
    refit_seconds: float = Field(default=30.0, ge=1.0, le=3600.0,
                                 description="the server refits at most this often")
    bootstrap: int = Field(default=200, ge=50, le=5000,
                           description="rater-bootstrap resamples in the server's refit")

    def trials_per_block(self, n_stimuli: int) -> int:
        return self.block_trials or n_stimuli
