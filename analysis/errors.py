"""The one exception type of the analysis package, and the range check of resample counts."""

from __future__ import annotations

from numbers import Integral

from stimuli_manifests.errors import ToolkitError


class AnalysisError(ToolkitError):
    """A problem the user can fix (bad path, unreadable input, nothing left to analyse).

    The message says what was wrong and what to do; the CLI prints it as one line.
    """


#: the most bootstrap resamples or split-halves a run may ask for: far more than any interval
#: needs (1000 is the default), and few enough that the resample matrices fit in memory
MAX_RESAMPLES = 100_000


def check_resamples(value: object, name: str) -> int:
    """``value`` as a count of resamples in [1, :data:`MAX_RESAMPLES`]; anything else is an
    :class:`AnalysisError` naming ``name`` (the option or argument)."""
    if isinstance(value, bool) or not isinstance(value, Integral) or \
            not 1 <= value <= MAX_RESAMPLES:
        raise AnalysisError(f"{name} must be a whole number from 1 to {MAX_RESAMPLES}, "
                            f"got {value}")
    return int(value)
