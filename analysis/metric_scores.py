"""Metric scores as read from ``cgvq-scores/1`` files: one row per (metric, stimulus).

Each row's ``direction`` (``higher-better``/``lower-better``) orients the metric so that higher
means better quality before anything is computed; a file without it is refused (the direction
is never guessed from the data). What the rows record of how a score was computed (versions,
settings, hashes) is kept per metric, and scores of a random backbone or uniform weights are
flagged wherever they appear. The optional ``title`` (1.1) is the name prose and figures
print; a metric without one is printed by its id.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from stimuli_manifests.errors import TableError
from stimuli_manifests.tables import DIRECTIONS, FORMAT_COLUMN, SCORES

from .data import InputProblem
from .errors import AnalysisError
from .spreadsheet_csv import read_cells

__all__ = ["MetricScores", "load_metric_scores", "metric_id"]

_FIX_DIRECTION = ("add a column 'direction' holding higher-better or lower-better for each "
                  "row (e.g. psnr,higher-better; flip,lower-better), or rewrite the file with "
                  "'cgvqm batch', which writes it")


# -- input --------------------------------------------------------------------------------
@dataclass
class MetricScores:
    """Scores of one or more metrics, one row per (metric, stimulus).

    ``frame`` columns: stimulus, metric (display id), score (as written), direction,
    oriented (score, negated for lower-better), backbone, _source, _row.
    """

    frame: pd.DataFrame
    problems: list[InputProblem] = field(default_factory=list)
    flags: dict[str, str] = field(default_factory=dict)
    #: metric -> why it gave no score (rows with an empty score and the scorer's note)
    not_applicable: dict[str, str] = field(default_factory=dict)
    #: metric -> the pixels per visual degree its scores were computed at (FLIP,
    #: ColorVideoVDP: the ``ppd`` of the scores' settings), for the panel's comparison
    ppd: dict[str, float] = field(default_factory=dict)
    #: metric -> what its rows record of how they were computed (versions, settings, the
    #: backbone's and weights' sha256), each the distinct values found
    provenance: dict[str, dict[str, list[Any]]] = field(default_factory=dict)
    #: metric -> the name prose and figures print (the ``title`` column; else the id)
    titles: dict[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        f = self.frame
        if "direction" not in f.columns:
            f["direction"] = "higher-better"
        if "oriented" not in f.columns:
            sign = np.where(f["direction"] == "lower-better", -1.0, 1.0)
            f["oriented"] = pd.to_numeric(f["score"], errors="coerce") * sign
        for col, default in (("_source", "<scores>"), ("_row", 0)):
            if col not in f.columns:
                f[col] = default
        if not self.flags:
            self.flags = provenance_flags(f)
        if not self.ppd:
            self.ppd = computed_ppd(f)
        if not self.provenance:
            self.provenance = score_provenance(f)
        if not self.titles:
            self.titles = metric_titles(f)

    @property
    def metrics(self) -> list[str]:
        return list(dict.fromkeys(self.frame["metric"]))

    def title(self, metric: str) -> str:
        """The name prose and figures print for ``metric``."""
        return self.titles.get(metric, metric)

    def direction(self, metric: str) -> str:
        return str(self.frame.loc[self.frame["metric"] == metric, "direction"].iloc[0])

    def untrained(self) -> dict[str, str]:
        """Metrics whose provenance makes them not the published metric -> why."""
        return dict(self.flags)


def metric_id(metric: str, pooling: object) -> str:
    """A metric's display name: ``metric`` plus ``(pooling)`` when a pooling is given."""
    if pooling is None or (isinstance(pooling, float) and np.isnan(pooling)) or pooling == "":
        return str(metric)
    return f"{metric} ({pooling})"


def metric_titles(frame: pd.DataFrame) -> dict[str, str]:
    """Metric id -> its title: the first non-blank ``title`` of its rows, else the id."""
    out: dict[str, str] = {}
    has = "title" in frame.columns
    for name, rows in frame.groupby("metric", sort=False):
        found = [t for t in rows["title"].dropna().astype(str).str.strip() if t] if has else []
        out[str(name)] = found[0] if found else str(name)
    return out


def _check_titles(f: pd.DataFrame) -> None:
    """One title per metric, and no title shared by two metrics (the prose could not tell
    them apart)."""
    if "title" not in f.columns:
        return
    named = f[f["title"] != ""]
    several = named.groupby("metric")["title"].unique()
    for name, titles in several.items():
        if len(titles) > 1:
            raise AnalysisError(f"metric {name!r} has several titles ("
                                + ", ".join(repr(str(t)) for t in titles)
                                + ") in the scores files; one metric has one title "
                                "(fix the 'title' column)")
    titles = metric_titles(f)
    seen: dict[str, str] = {}
    for name, title in titles.items():
        if title in seen:
            raise AnalysisError(f"metrics {seen[title]!r} and {name!r} share the title "
                                f"{title!r}; give each its own title (the 'title' column) "
                                "so the text and figures can tell them apart")
        seen[title] = name


def _settings_flags(text: object) -> list[str]:
    if not isinstance(text, str) or not text.strip().startswith("{"):
        return []
    try:
        settings = json.loads(text)
    except json.JSONDecodeError:
        return []
    out = []
    if isinstance(settings, dict):
        if settings.get("random_backbone") not in (None, False, "", 0):
            out.append("random backbone")
        if str(settings.get("weights", "")).lower() == "uniform":
            out.append("uniform weights")
    return out


def _settings_ppd(text: object) -> float | None:
    if not isinstance(text, str) or not text.strip().startswith("{"):
        return None
    try:
        ppd = json.loads(text).get("ppd")
    except (json.JSONDecodeError, AttributeError):
        return None
    return float(ppd) if isinstance(ppd, int | float) and np.isfinite(ppd) else None


def computed_ppd(frame: pd.DataFrame) -> dict[str, float]:
    """Metric -> the pixels per degree its settings name, where every row names the same."""
    if "settings" not in frame.columns:
        return {}
    out = {}
    for metric, rows in frame.groupby("metric", sort=False):
        values = {_settings_ppd(t) for t in rows["settings"]}
        if len(values) == 1 and None not in values:
            out[str(metric)] = float(values.pop())  # type: ignore[arg-type]
    return out


PROVENANCE_COLUMNS = ("versions", "settings", "backbone", "backbone_sha256", "weights_sha256")
"""The columns of a scores row that say how its score was computed (JSON for the first two)."""


def score_provenance(frame: pd.DataFrame) -> dict[str, dict[str, list[Any]]]:
    """Metric -> column -> the distinct values its rows record (JSON cells parsed): what a
    reviewer needs to know which implementation, settings and weights gave the numbers."""
    out: dict[str, dict[str, list[Any]]] = {}
    columns = [c for c in PROVENANCE_COLUMNS if c in frame.columns]
    for name, rows in frame.groupby("metric", sort=False):
        found: dict[str, list[Any]] = {}
        for col in columns:
            values = []
            for cell in rows[col].dropna().astype(str).str.strip().unique():
                if not cell:
                    continue
                try:
                    value = json.loads(cell) if cell.startswith("{") else cell
                except ValueError:
                    value = cell
                if value not in values:
                    values.append(value)
            if values:
                found[col] = values
        if found:
            out[str(name)] = found
    return out


def provenance_flags(frame: pd.DataFrame) -> dict[str, str]:
    """Metric -> warning for scores from a random (untrained) backbone or uniform weights."""
    flags: dict[str, list[str]] = {}
    for _, row in frame.iterrows():
        found = []
        backbone = row.get("backbone")
        if isinstance(backbone, str) and "random" in backbone.lower():
            found.append(f"random (untrained) backbone: {backbone}")
        weights = row.get("weights_sha256")
        if isinstance(weights, str) and weights.strip().lower() == "uniform":
            found.append("uniform feature weights (not a calibrated metric)")
        found += _settings_flags(row.get("settings"))
        if str(row["metric"]).split(" (")[0].endswith("-uniform"):
            found.append("uniform feature weights (not a calibrated metric)")
        for item in found:
            lst = flags.setdefault(str(row["metric"]), [])
            if item not in lst and not any(item in x or x in item for x in lst):
                lst.append(item)
    return {m: "; ".join(v) for m, v in flags.items()}


def _read_scores_csv(path: Path) -> pd.DataFrame:
    """One scores file as text cells (read as spreadsheets write CSV: ``;`` or tab between
    columns with decimal commas, names in any case), its contract and directions checked."""
    if path.is_dir():
        raise AnalysisError(f"--metric {path} is a folder; give the scores CSV file "
                            "('cgvqm batch --out' wrote it)")
    f = read_cells(path, what="metric scores file", columns=SCORES.columns, decimals=("score",))
    if "direction" not in f.columns and {"stimulus", "metric", "score"} <= set(f.columns):
        raise AnalysisError(f"metric scores file {path} has no 'direction' column: "
                            + _FIX_DIRECTION)
    try:
        SCORES.check(list(f.columns),
                     [v for v in f[FORMAT_COLUMN] if v] if FORMAT_COLUMN in f.columns else None,
                     path)
    except TableError as exc:
        raise AnalysisError(str(exc)) from None
    if f.empty:
        raise AnalysisError(f"metric scores file {path} has a header but no rows")
    for column in ("metric", "stimulus"):  # an empty id would become a metric called 'nan'
        empty = f[column] == ""
        if empty.any():
            raise AnalysisError(f"metric scores file {path}: column '{column}' is empty on "
                                f"line(s) {_rows_text(f['_row'][empty].astype(int).tolist())}; "
                                "every row names its metric and stimulus")
    direction = f["direction"].str.lower()
    bad = sorted(set(direction) - set(DIRECTIONS))
    if bad:
        raise AnalysisError(f"metric scores file {path}: direction {bad[0]!r} is not one of "
                            f"{', '.join(DIRECTIONS)}; " + _FIX_DIRECTION)
    f["direction"] = direction
    return f.reset_index(drop=True)


def _rows_text(rows: list[int]) -> str:
    """Line numbers as short ranges: ``2-17``, ``2, 5, 9-11``."""
    spans: list[list[int]] = []
    for r in sorted(rows):
        if spans and r == spans[-1][1] + 1:
            spans[-1][1] = r
        else:
            spans.append([r, r])
    text = [f"{a}-{b}" if b > a else f"{a}" for a, b in spans]
    return ", ".join(text[:6]) + (", ..." if len(text) > 6 else "")


def _shown(value: object) -> str | None:
    """A score cell as the user wrote it (``'abc'``, ``inf``); None when empty or NaN."""
    if isinstance(value, str):
        text = value.strip()
        if text.lower() in ("", "nan", "na", "n/a", "null", "none"):
            return None  # written as "no number": said as empty or NaN
        return repr(text)
    try:
        number = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return repr(str(value))
    return None if np.isnan(number) else f"{number:g}"


def _no_numeric_score(rows: pd.DataFrame, raw: pd.Series) -> str:
    """Why no row of the score files is usable: the 'score' column of every row is empty, NaN
    or not a number (file, lines and an example value)."""
    parts = []
    for source, group in rows.groupby("_source", sort=False):
        shown = [s for s in map(_shown, raw.loc[group.index]) if s is not None]
        example = f"e.g. {shown[0]}" if shown else "empty or NaN"
        parts.append(f"metric scores file {source}: column 'score' is not a finite number in "
                     f"every row (lines {_rows_text(group['_row'].astype(int).tolist())}; "
                     f"{example})")
    return "; ".join(parts) + "; every score must be a number (rerun the scorer, or fix " \
        "those rows)"


def _refuse_conflicting_scores(f: pd.DataFrame) -> None:
    """Two different scores of one metric for one stimulus: keeping either would be a silent
    choice (two files that both hold a metric of this name, say), so the run stops."""
    twice = f[f.duplicated(["metric", "stimulus"], keep=False)]
    for (metric, stimulus), rows in twice.groupby(["metric", "stimulus"], sort=False):
        if rows["score"].nunique() < 2:
            continue  # the same number twice: left out below, with a warning
        where = ", ".join(f"{src}:{int(line)}" for src, line in zip(rows["_source"], rows["_row"],
                                                                    strict=True))
        files = set(rows["_source"])
        fix = ("two files hold a metric of this name: rename the metric in one of them, or "
               "leave one file out" if len(files) > 1 else
               "a scores file holds one row per metric and stimulus: remove the extra row")
        raise AnalysisError(f"metric {metric!r} has {len(rows)} different scores for "
                            f"{stimulus} ({where}); {fix}")


def load_metric_scores(paths: list[str | Path]) -> MetricScores:
    """Read metric score CSVs (``cgvq-scores/1``); bad rows are reported and left out."""
    problems: list[InputProblem] = []
    f = pd.concat([_read_scores_csv(Path(p)) for p in paths], ignore_index=True)
    pooling = f["pooling"] if "pooling" in f.columns else pd.Series([None] * len(f))
    if "title" in f.columns:  # a pooled metric's title names its pooling, as its id does
        title = f["title"].fillna("").astype(str).str.strip()
        f["title"] = [metric_id(t, p) if t else "" for t, p in zip(title, pooling, strict=True)]
    f["metric"] = [metric_id(m, p) for m, p in zip(f["metric"], pooling, strict=True)]
    _check_titles(f)
    both = f.groupby("metric")["direction"].nunique()
    if (both > 1).any():
        name = both[both > 1].index[0]
        files = ", ".join(dict.fromkeys(f.loc[f["metric"] == name, "_source"]))
        raise AnalysisError(f"metric {name!r} is marked both higher-better and lower-better "
                            f"(in {files}); one metric has one direction")
    raw = f["score"]
    f["score"] = pd.to_numeric(f["score"], errors="coerce")
    bad = ~np.isfinite(f["score"].to_numpy(dtype=float))
    # an empty score with the scorer's note is a metric that does not apply (too small a
    # frame, say), not a broken input
    counts: dict[str, list] = {}
    for _, row in f[bad].iterrows():
        note = row.get("note")
        if isinstance(note, str) and note.strip() and pd.isna(row.get("score")):
            entry = counts.setdefault(row["metric"], [0, note.strip()])
            entry[0] += 1
            continue
        problems.append(InputProblem(row["_source"], int(row["_row"]),
                                     f"score of {row['metric']} for {row['stimulus']} is missing "
                                     f"or not a number; row left out"))
    not_applicable = {m: f"{why} ({n} stimul{'us' if n == 1 else 'i'} without a score)"
                      for m, (n, why) in counts.items()}
    flags = provenance_flags(f)
    broken = bad & ~f["metric"].isin(list(counts)).to_numpy()
    if broken.any() and bad.all():
        raise AnalysisError(_no_numeric_score(f[broken], raw[broken]))
    f = f[~bad]
    _refuse_conflicting_scores(f)
    dup = f.duplicated(["metric", "stimulus"], keep="first")
    for _, row in f[dup].iterrows():
        problems.append(InputProblem(row["_source"], int(row["_row"]),
                                     f"second score of {row['metric']} for {row['stimulus']}; "
                                     "left out"))
    f = f[~dup].copy()
    if "backbone" not in f.columns:
        f["backbone"] = None
    f["oriented"] = np.where(f["direction"] == "lower-better", -f["score"], f["score"])
    return MetricScores(f.reset_index(drop=True), problems, flags, not_applicable)
