"""Tidy ratings CSVs as analysis input, held to the rules session files are held to.

A CSV carries no checksum chain, but its rows still name their study, session and (from
``cgvq-ratings/1.1`` on) manifest version. Rows of another study or version are refused as
such a session file is, and duplicates are settled by which session came first (its
earliest ``presented_at``), not by the order the files were given in.
"""

from __future__ import annotations

import zipfile
import zlib
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from stimuli_manifests.errors import TableError
from stimuli_manifests.tables import FORMAT_COLUMN, RATINGS

from .data import Exclusion
from .errors import AnalysisError

_REQUIRED = ("participant", "stimulus", "rating")
_TEXT_COLUMNS = ("participant", "stimulus", "reference", "session", "study", "manifest_sha256",
                 FORMAT_COLUMN)


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
    the analysis needs; ``_source``/``_row`` name each row for messages."""
    if path.is_dir():
        raise AnalysisError(f"ratings file {path} is a folder; give the CSV file itself (or "
                            "a folder of session files to --sessions)")
    _refuse_session_export(path)
    try:
        frame = pd.read_csv(path, dtype={c: str for c in _TEXT_COLUMNS})
    except FileNotFoundError:
        raise AnalysisError(f"ratings file {path} does not exist") from None
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError, ValueError,
            EOFError, OSError, zlib.error) as exc:
        raise AnalysisError(f"ratings file {path} is not a readable CSV ({exc})") from None
    if FORMAT_COLUMN in frame.columns:
        try:
            RATINGS.check_versions(frame[FORMAT_COLUMN].dropna().tolist(), path)
        except TableError as exc:
            raise AnalysisError(str(exc)) from None
    missing = [c for c in _REQUIRED if c not in frame.columns]
    if missing:
        raise AnalysisError(
            f"ratings file {path} lacks column(s) {', '.join(missing)}; it must be the tidy "
            f"ratings table ({RATINGS.version}: {', '.join(RATINGS.required)}; the analysis "
            "needs at least participant, stimulus and rating)"
        )
    frame["_source"] = str(path)
    frame["_row"] = np.arange(len(frame)) + 2  # line number: header is line 1
    return frame


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


def frame_from_csvs(paths: Sequence[Path], study_id: str, manifest_sha256: str
                    ) -> tuple[pd.DataFrame, list[Exclusion]]:
    """The rows of ``paths`` that belong to ``study_id`` and this manifest version, ranked by
    session start; and what was refused. Nothing left is an error."""
    frame = pd.concat([read_csv(Path(p)) for p in paths], ignore_index=True)
    frame, exclusions = other_study_rows(frame, study_id)
    frame, other_version = other_version_rows(frame, manifest_sha256)
    exclusions += other_version
    if frame.empty and exclusions:
        raise AnalysisError("no ratings of this study in " + ", ".join(map(str, paths)) + ": "
                            + "; ".join(str(x) for x in exclusions[:3]))
    return rank_sessions(frame), exclusions
