"""Files other tools read: the DMOS CSV, a SUREAL dataset, the ITU-T P.910 rating matrix."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pandas as pd

from stimuli_manifests.tables import DMOS, write_table

from .data import RatingSet
from .scores import ScoreResult, dmos_table
from .sureal_io import write_sureal_json

DMOS_COLUMNS = DMOS.required


def _cell(value: Any) -> Any:
    if value is None or value is pd.NA:
        return ""
    if isinstance(value, float) and not math.isfinite(value):
        return ""
    return value


def write_dmos_csv(rs: RatingSet, res: ScoreResult, path: str | Path, *,
                   quality: bool = True) -> Path:
    """The DMOS table (``cgvq-dmos/1``): contract columns, then scene, the model's raw quality
    and its CI, and the hidden-reference flag; last column ``format``."""
    table = dmos_table(rs, res)
    if not quality:
        table = table.drop(columns=["quality", "quality_ci95_low", "quality_ci95_high"])
    rows = [{k: _cell(v) for k, v in row.items()} for row in table.to_dict("records")]
    return write_table(path, DMOS, rows, columns=list(table.columns))


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


def write_exports(rs: RatingSet, res: ScoreResult, out: str | Path, *,
                  raw: RatingSet | None = None) -> dict[str, Path]:
    """All three exports into folder ``out``: the DMOS of ``rs`` (the raters used), and the
    SUREAL dataset and P.910 matrix of ``raw`` (every rater as read; default ``rs``) so the
    screening can be re-run elsewhere."""
    out = Path(out)
    raw = raw or rs
    return {
        "dmos": write_dmos_csv(rs, res, out / "dmos.csv"),
        "sureal": write_sureal_json(raw, out / "sureal_dataset.json"),
        "p910_matrix": write_rating_matrix(raw, out / "rating_matrix_p910.csv"),
    }
