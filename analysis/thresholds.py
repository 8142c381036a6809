"""The data-quality flag thresholds: one home for the report, its methods section and the
study server's dashboard (which reads them without the statistics stack)."""

from __future__ import annotations

THRESHOLDS: dict[str, float] = {
    "completeness": 0.9,        # below: "incomplete" flag (dropping is --min-completeness)
    "dropped_trials": 0.05,     # share of presentations with dropped frames
    "viewing_s": 1.0,           # median viewing time per trial, seconds
    "hidden_reference": 0.5,    # mean hidden-reference rating below this share of the scale
    "loo_r": 0.75,              # correlation with the leave-one-out panel mean (P.913 r1)
    "repeat_r": 0.5,            # mean correlation between a rater's repetitions
}
