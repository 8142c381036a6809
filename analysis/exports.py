"""Files other tools read: the DMOS CSV, a SUREAL dataset, the ITU-T P.910 rating matrix."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from .data import RatingSet
from .scores import ScoreResult, dmos_table
from .sureal_io import write_sureal_json

DMOS_COLUMNS = ("stimulus", "reference", "method", "level", "dmos", "ci95_low", "ci95_high",
                "mos", "n_ratings", "model")


def write_dmos_csv(rs: RatingSet, res: ScoreResult, path: str | Path, *,
                   quality: bool = True) -> Path:
    """DMOS contract (DESIGN.md 5) columns first, then scene, quality and its CI."""
    table = dmos_table(rs, res)
    if not quality:
        table = table.drop(columns=["quality", "quality_ci95_low", "quality_ci95_high"])
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    table.to_csv(path, index=False)
    return path


def rating_matrix(rs: RatingSet) -> pd.DataFrame:
    """ITU-T P.910 rating matrix: rows stimuli, columns raters (repetitions as extra columns
    ``rater#2``, ``rater#3``...), NaN for gaps."""
    cols = {}
    for r in range(rs.n_repetitions):
        for s, rater in enumerate(rs.raters):
            name = rater if r == 0 else f"{rater}#{r + 1}"
            cols[name] = rs.scores[:, s, r]
    return pd.DataFrame(cols, index=pd.Index(rs.stimulus_ids, name="stimulus"))


def write_rating_matrix(rs: RatingSet, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    rating_matrix(rs).to_csv(path, na_rep="NaN")
    return path


def write_exports(rs: RatingSet, res: ScoreResult, out: str | Path) -> dict[str, Path]:
    """All three exports into folder ``out``."""
    out = Path(out)
    return {
        "dmos": write_dmos_csv(rs, res, out / "dmos.csv"),
        "sureal": write_sureal_json(rs, out / "sureal_dataset.json"),
        "p910_matrix": write_rating_matrix(rs, out / "rating_matrix_p910.csv"),
    }
