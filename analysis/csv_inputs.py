"""Tidy ratings CSVs as analysis input, held to the rules session files are held to.

A CSV carries no checksum chain, but its rows still name their study, session and (from
``cgvq-ratings/1.1`` on) manifest version. Rows of another study or version are refused as
such a session file is, and duplicates are settled by which session came first (its
earliest ``presented_at``), not by the order the files were given in.
"""

from __future__ import annotations

import re
import zipfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from session_store.pull_listing import ServerWithdrawal
from stimuli_manifests.errors import TableError
from stimuli_manifests.tables import FORMAT_COLUMN, RATINGS

from .data import Exclusion
from .errors import AnalysisError
from .sessions import WITHDRAWAL_RULE, without_file
from .spreadsheet_csv import read_cells, read_decimal_commas

_REQUIRED = ("participant", "stimulus", "rating")


def _refuse_session_export(path: Path) -> None:
    """A session export (a zip holding a ``.sqlite``) given as ratings: say where it goes."""
    if path.suffix.lower() != ".zip" or not zipfile.is_zipfile(path):
        return
    try:
        with zipfile.ZipFile(path) as zf:
            names = zf.namelist()
    except (zipfile.BadZipFile, OSError):
        return
    if any(n.endswith(".sqlite") for n in names):
        raise AnalysisError(f"{path} is a session export (it holds a session file): give it "
                            "to --sessions, not --ratings")


def read_csv(path: Path) -> pd.DataFrame:
    """One ratings CSV (plain or compressed, as pandas infers from the name) with the columns
    the analysis needs; ``_source``/``_row`` name each row for messages.

    Read the way spreadsheets write them: commas, or semicolons or tabs between columns (the
    header decides), then decimal commas in ``rating`` and ``repetition``; column names in
    any case; ids without surrounding spaces; empty lines and rows of empty cells (Excel's
    trailing ``,,``) skipped, with line numbers still those of the file."""
    if path.is_dir():
        raise AnalysisError(f"ratings file {path} is a folder; give the CSV file itself (or "
                            "a folder of session files to --sessions)")
    _refuse_session_export(path)
    frame = read_cells(path, what="ratings file",
                       columns=(*RATINGS.required, *RATINGS.optional, FORMAT_COLUMN))
    data = [c for c in frame.columns if not str(c).startswith("_")]
    if FORMAT_COLUMN in frame.columns:
        try:
            RATINGS.check_versions([v for v in frame[FORMAT_COLUMN] if v != ""], path)
        except TableError as exc:
            raise AnalysisError(str(exc)) from None
    if "stimulus" in frame.columns and "participant" not in frame.columns and \
            "rating" not in frame.columns:
        sep = frame.attrs["sep"]
        frame = melt_rating_matrix(frame, path)
        frame.attrs["sep"] = sep  # the decimal commas below depend on it
    missing = [c for c in _REQUIRED if c not in frame.columns]
    if missing:
        shown = ", ".join(str(c) for c in data[:8]) + (", ..." if len(data) > 8 else "")
        raise AnalysisError(
            f"ratings file {path} lacks column(s) {', '.join(missing)} (its columns: "
            f"{shown}); the analysis needs participant, stimulus and rating: name yours so "
            f"(the other columns of the tidy ratings table, {RATINGS.version}, are optional)")
    read_decimal_commas(frame, path, "ratings file", ("rating", "repetition"))
    return frame


#: Columns of a wide matrix that hold no rater's ratings (its stimulus's facts, aggregates).
_NOT_RATERS = frozenset({"reference", "scene", "method", "level", "setting", "is_hidden_reference",
                         "format", "mos", "dmos", "mean", "std", "sd", "var", "ci", "ci95",
                         "n", "count", "n_ratings", "path"})
_REPEAT = re.compile(r"^(?P<rater>.+)#(?P<rep>[1-9]\d*)$")


def melt_rating_matrix(frame: pd.DataFrame, path: Path) -> pd.DataFrame:
    """A wide ITU-T P.910 rating matrix (one row per stimulus, one column per rater, as the
    report's ``rating_matrix_p910.csv`` and many published datasets hold it; ``rater#2``
    columns for repetitions) in the tidy layout: one row per rating, empty and ``NaN``
    cells left out. The line numbers stay the matrix's."""
    raters = [c for c in frame.columns if not str(c).startswith("_") and c != "stimulus"
              and str(c).strip().lower() not in _NOT_RATERS]
    if len(raters) < 2:
        raise AnalysisError(
            f"ratings file {path} has a stimulus column but neither participant nor rating: "
            "give the tidy table (participant, stimulus, rating), or a rating matrix with one "
            "column per rater")
    rows = []
    for column in raters:
        m = _REPEAT.fullmatch(str(column))
        rater, rep = (m["rater"], int(m["rep"])) if m else (str(column), 1)
        cells = frame[column].astype(str).str.strip()
        rated = ~cells.str.lower().isin(["", "nan", "na", "n/a", "-"])
        rows.append(pd.DataFrame({"participant": rater, "stimulus": frame["stimulus"][rated],
                                  "rating": cells[rated], "repetition": str(rep),
                                  "_source": frame["_source"][rated],
                                  "_row": frame["_row"][rated]}))
    tidy = pd.concat(rows, ignore_index=True)
    tidy.attrs.update(frame.attrs)
    return tidy


def _blank(values: pd.Series) -> np.ndarray:
    return values.isna().to_numpy() | values.astype(str).str.strip().isin(["", "nan"]).to_numpy()


def other_study_rows(frame: pd.DataFrame, study_id: str) -> tuple[pd.DataFrame, list[Exclusion]]:
    """Rows of this study (and rows that do not say), and one refusal per file and other
    study named in the ``study`` column."""
    if "study" not in frame.columns:
        return frame, []
    study = frame["study"]
    other = ~_blank(study) & (study.astype(str) != study_id).to_numpy()
    exclusions = [
        Exclusion("refused session", f"{src} ({n} rows)",
                  f"belongs to study {name!r}, not to this manifest's study {study_id!r}",
                  "ratings rows' study must equal the manifest's study_id")
        for (src, name), n in frame.loc[other].groupby(["_source", "study"], sort=True)
        .size().items()]
    return frame.loc[~other], exclusions


def other_version_rows(frame: pd.DataFrame, manifest_sha256: str
                       ) -> tuple[pd.DataFrame, list[Exclusion]]:
    """Rows whose ``manifest_sha256`` (ratings tables from 1.1 on) names another manifest
    version are refused, as their session files are: after ``serve --new-version`` an id may
    name another video. Rows that do not say are kept (tables before 1.1)."""
    if "manifest_sha256" not in frame.columns:
        return frame, []
    sha = frame["manifest_sha256"]
    other = ~_blank(sha) & (sha.astype(str) != manifest_sha256).to_numpy()
    exclusions = [
        Exclusion("refused session", f"{src} ({n} rows)",
                  f"was run with another manifest (sha256 {name[:12]}..., this one is "
                  f"{manifest_sha256[:12]}...); analyse it with the manifest the participants "
                  f"saw ('cgvq-study pull' saves it as manifest.{name[:12]}.json)",
                  "ratings rows' manifest_sha256 must equal the manifest file's sha256")
        for (src, name), n in frame.loc[other].groupby(["_source", "manifest_sha256"],
                                                        sort=True).size().items()]
    return frame.loc[~other], exclusions


def rank_sessions(frame: pd.DataFrame) -> pd.DataFrame:
    """``_rank`` for each row: sessions in the order they started (their earliest
    ``presented_at``, then the session id), so that of a rating given in two sessions the
    earlier session's counts, whatever the order of files and rows. Rows without a session or
    a time keep the order they were read in, after the timed ones."""
    if "session" not in frame.columns or "presented_at" not in frame.columns:
        return frame.assign(_rank=0)
    at = pd.to_datetime(frame["presented_at"], errors="coerce", utc=True, format="ISO8601")
    session = frame["session"].where(~_blank(frame["session"]))
    started = at.groupby([frame["participant"], session]).transform("min")
    timed = session.notna() & started.notna()
    keys = pd.DataFrame({"t": started.where(timed), "s": session.where(timed)})
    order = keys.loc[timed].drop_duplicates().sort_values(["t", "s"])
    rank = {(t, s): i for i, (t, s) in enumerate(order.itertuples(index=False, name=None))}
    ranks = [rank.get((t, s), len(rank)) if ok else len(rank)
             for t, s, ok in zip(keys["t"], keys["s"], timed, strict=True)]
    return frame.assign(_rank=ranks)


def withdrawn_rows(frame: pd.DataFrame, deleted: dict[str, ServerWithdrawal]
                   ) -> tuple[pd.DataFrame, list[Exclusion]]:
    """Rows of participants withdrawn on the server (a pull listing beside the table says
    so): a table written before the withdrawal still holds them. Refused, one line per file
    and participant; a withdrawn participant without rows is counted as withdrawn too."""
    if not deleted or "participant" not in frame.columns:
        return frame, [without_file(w) for _, w in sorted((deleted or {}).items())]
    who = frame["participant"].astype(str).str.strip()
    gone = who.isin(list(deleted)).to_numpy()
    exclusions = [
        Exclusion("refused session", f"{src} ({n} rows)",
                  deleted[pid].words() + ": these rows must not be used; delete them",
                  WITHDRAWAL_RULE)
        for (src, pid), n in frame.loc[gone].assign(_who=who[gone])
        .groupby(["_source", "_who"], sort=True).size().items()]
    present = set(who)
    exclusions += [without_file(w) for pid, w in sorted(deleted.items()) if pid not in present]
    return frame.loc[~gone], exclusions


def frame_from_csvs(paths: Sequence[Path], study_id: str, manifest_sha256: str,
                    deleted: dict[str, ServerWithdrawal] | None = None
                    ) -> tuple[pd.DataFrame, list[Exclusion]]:
    """The rows of ``paths`` that belong to ``study_id`` and this manifest version, ranked by
    session start; and what was refused (``deleted``: participants withdrawn on the server,
    see :func:`session_store.pull_listing.server_withdrawals`). Nothing left is an error."""
    frame = pd.concat([read_csv(Path(p)) for p in paths], ignore_index=True)
    frame, exclusions = other_study_rows(frame, study_id)
    frame, other_version = other_version_rows(frame, manifest_sha256)
    exclusions += other_version
    frame, withdrawn = withdrawn_rows(frame, deleted or {})
    exclusions += withdrawn
    if frame.empty and exclusions:
        raise AnalysisError("no ratings of this study in " + ", ".join(map(str, paths)) + ": "
                            + "; ".join(str(x) for x in exclusions[:3]))
    return rank_sessions(frame), exclusions
