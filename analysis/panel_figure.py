"""The post-study survey as a figure: one diverging stacked bar per Likert question.

Each bar shows the shares of the answers to one question, the disagreeing points to the left
of zero and the agreeing ones to the right (the middle point of an odd scale split across
zero), so the balance of opinion reads at a glance, as in the survey figure of the CGVQM+D
paper. "Prefer not to say" and unanswered are left out of the shares and counted in the label.
"""

from __future__ import annotations

import textwrap
from collections import Counter
from pathlib import Path

import numpy as np
from matplotlib import colormaps
from matplotlib.figure import Figure

from stimuli_manifests.panel import Likert, Panel

from .panel import PanelSummary, QuestionSummary, likert_keys


def likert_shares(q: QuestionSummary, points: list[str]) -> tuple[np.ndarray, int]:
    """Share of each point among the answers that chose a point, and how many did (points
    are looked up by position, so repeated point labels are not counted twice)."""
    counts = np.array([q.counts.get(k, 0) for k in likert_keys(points)], dtype=float)
    n = int(counts.sum())
    return (counts / n if n else counts), n


def survey_questions(definition: Panel) -> tuple[list[str], list[str]]:
    """(question ids, points) of the figure: the Likert questions of the post-study
    questionnaires (of all questionnaires when there is none after the trials) that share
    the most common scale, so that one legend reads for every bar."""
    after = [q for qn in definition.questionnaires_at("after") for q in qn.questions()
             if isinstance(q, Likert)]
    likert = after or [q for qn in definition.questionnaires for q in qn.questions()
                       if isinstance(q, Likert)]
    if not likert:
        return [], []
    points = Counter(tuple(q.points) for q in likert).most_common(1)[0][0]
    return [q.id for q in likert if tuple(q.points) == points], list(points)


def draw_survey(summary: PanelSummary, definition: Panel, path: Path) -> Path | None:
    """Diverging stacked bars of the survey's Likert questions; None when there is none."""
    ids, scale = survey_questions(definition)
    by_id = {q.id: q for q in summary.likert()}
    questions = [by_id[i] for i in ids if i in by_id]
    if not questions:
        return None
    points_of = {q.id: scale for q in questions}
    fig = Figure(figsize=(9.0, 1.0 + 0.62 * len(questions)))
    ax = fig.add_subplot()
    width = max(len(points_of[q.id]) for q in questions)
    cmap = colormaps["RdBu"]
    legend_done: set[str] = set()
    for row, q in enumerate(questions):
        points = points_of[q.id]
        shares, n = likert_shares(q, points)
        k = len(points)
        mid = (k - 1) / 2
        left = -(shares[: k // 2].sum() + (shares[k // 2] / 2 if k % 2 else 0.0))
        for i, (point, share) in enumerate(zip(likert_keys(points), shares, strict=True)):
            color = cmap(0.1 + 0.8 * i / (k - 1))
            if k % 2 and i == int(mid):
                color = (0.8, 0.8, 0.8, 1.0)
            label = point if point not in legend_done else None
            legend_done.add(point)
            ax.barh(row, share * 100, left=left * 100, color=color, edgecolor="white",
                    height=0.7, label=label)
            if share >= 0.08:
                ax.text((left + share / 2) * 100, row, f"{share:.0%}", ha="center",
                        va="center", fontsize=7)
            left += share
        ax.text(101, row, f"n={n}", va="center", fontsize=7)
    ax.set_yticks(range(len(questions)),
                  [textwrap.fill(q.text, 48) for q in questions], fontsize=7)
    ax.invert_yaxis()
    ax.axvline(0, color="0.3", lw=0.8)
    ax.set_xlim(-100, 110)
    ax.set_xticks([-100, -50, 0, 50, 100], ["100%", "50%", "0", "50%", "100%"])
    ax.legend(fontsize=7, ncol=width, loc="upper center", bbox_to_anchor=(0.45, -0.12 if
              len(questions) > 2 else -0.3), frameon=False)
    ax.set_title("post-study survey: share of answers per question (left: disagree, right: "
                 "agree)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    fig.savefig(path.with_suffix(".pdf"))  # vector, for papers, as every report figure
    return path
