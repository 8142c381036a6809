"""The one exception type of ``cgvqm_core``.

Everything a user can cause (missing or corrupt video, mismatched frame rates, weights that
fail their hash check, no backbone available offline) is raised as :class:`CGVQMError` with a
message that says what was wrong and what to do. The CLI turns it, and the video reader's
``StimuliError``, into one line on stderr and exit code 2.
"""

from __future__ import annotations

from stimuli_manifests.errors import ToolkitError


class CGVQMError(ToolkitError):
    """A problem with the metric's inputs, weights or options that the user can fix."""


def key_mismatch(missing: list[str], unexpected: list[str]) -> str:
    """How a refused state dict differs from the expected one (counts and a few names)."""
    parts = []
    if missing:
        parts.append(f"missing {len(missing)} (e.g. {', '.join(missing[:3])})")
    if unexpected:
        parts.append(f"unexpected {len(unexpected)} (e.g. {', '.join(unexpected[:3])})")
    return "; ".join(parts)
