"""Session files in: which belong to the study, which do not, and what each participant did.

Session files are read only through :mod:`session_store`: :func:`session_sources` finds
them in files, folders and exported zips (checked against their checksums), and
:func:`read_session` reads each in one read transaction, WAL included. Before any rating is
used, every session is checked against the manifest: a withdrawn session, a session of another
study (``study_id``), one run with another manifest (``manifest_sha256``) or one altered in
transit is refused, listed as an :class:`~analysis.data.Exclusion` and never mixed into the
ratings. Copies of one session (same session id in several files) are reduced to one; several
sessions of one participant are merged, the earlier session's rating winning when both rated
the same stimulus and repetition. Every choice is independent of the order of the files.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from session_store import SessionInfo, StudyError, read_session, session_sources
from session_store.answers import ENDED_BY_VISION_CHECK
from session_store.pull_listing import ServerWithdrawal

from .data import Exclusion, InputProblem
from .errors import AnalysisError

log = logging.getLogger(__name__)

SESSION_SUFFIXES = (".sqlite",)
INTEGRITY_FAILURES = ("hash chain broken", "the session record counts", "sequence number",
                      "rating row does not match the planned trial")
"""How :mod:`session_store`'s chain check words a file changed outside the app."""


@dataclass
class Session:
    """What the analysis needs from one session file (read once, then closed): the session
    record as the session store reads it (``info``), its rows, and what was found wrong."""

    path: str
    info: SessionInfo
    ratings: list[dict[str, Any]]
    presentations: list[dict[str, Any]]
    n_planned: int
    problems: list[InputProblem] = field(default_factory=list)
    damaged: str = ""  # why the file cannot be trusted (altered in transit); empty if fine
    answers: list[dict[str, Any]] = field(default_factory=list)
    screenings: list[dict[str, Any]] = field(default_factory=list)
    events: list[dict[str, Any]] = field(default_factory=list)
    name: str = ""
    """The file's name relative to the ``--sessions`` path it was found under (see
    :class:`session_store.sources.SessionSource`): what the report's tables record."""

    @property
    def altered(self) -> str:
        """Where the session file fails its own integrity check (a rating row edited, removed
        or added outside the app), in words; empty when intact. The ratings before that point
        are authentic and used; the ones from there on are not."""
        for p in self.problems:
            if p.message.startswith(INTEGRITY_FAILURES):
                where = f" at trial {p.row}" if p.row is not None else ""
                return f"{p.message.split(':')[0]}{where}"
        return ""

    @property
    def ended_by(self) -> str:
        """The vision check that ended this session (``on_fail: end``), or empty."""
        return next((str(e.get("test") or "vision") for e in self.events
                     if e.get("kind") == ENDED_BY_VISION_CHECK), "")

    @property
    def timing_mode(self) -> str:
        """``vsync`` for participant runs, ``paced-pilot`` when the experimenter allowed
        running without vsync, ``simulated`` for ``cgvq-study simulate``'s raters (no
        display); empty when the session predates the setting."""
        settings = self.info.settings or {}
        mode = settings.get("timing_mode")
        if not mode and settings.get("simulated"):
            return "simulated"
        return str(mode or "")

    @property
    def vsync(self) -> bool | None:
        value = (self.info.display or {}).get("vsync")
        return None if value is None else bool(value)

    @property
    def order_key(self) -> tuple[str, str, str]:
        """Sessions are ranked by start time, then session id, then path (deterministic)."""
        return (self.info.started_at or self.info.created_at or "", self.info.session_id,
                self.path)


@contextlib.contextmanager
def session_files(paths: Sequence[str | Path]) -> Iterator[tuple[list, list[InputProblem]]]:
    """The session sources in ``paths`` (files, folders, zips) and the notes about them.
    A path that does not exist, or a named folder or zip without session files, is an error;
    a zip without one found inside a folder (screenshots, say) is a note."""
    named = {Path(p).resolve() for p in paths}
    with session_sources(paths) as (sources, found):
        notes = []
        for prob in found:
            where = Path(prob.path)
            if prob.nothing_to_check and not where.exists():
                raise AnalysisError(f"session path {where} does not exist")
            if prob.nothing_to_check and where.resolve() in named:
                # what was named holds nothing; a stray zip found in a folder is only noted
                raise AnalysisError(f"no session files (*.sqlite) in {where}")
            notes.append(InputProblem(str(where), prob.row, prob.message))
        if not sources:
            if notes:  # say what is wrong with what was given (a damaged zip, say)
                raise AnalysisError("no readable session file in " + ", ".join(map(str, paths))
                                    + ": " + "; ".join(str(n) for n in notes[:3]))
            raise AnalysisError("no session files (*.sqlite) in " + ", ".join(map(str, paths)))
        yield sources, notes


def missing_from_pull(paths: Sequence[str | Path], records: Sequence[Session]
                      ) -> list[InputProblem]:
    """Participants the pull's listing (``server_listing.json`` in a sessions folder) names
    with ratings whose session is not among the files read: a folder copied without them
    would shift every number with no word said."""
    import json

    from session_store.protocol import PULL_LISTING_FILE

    seen = {rec.info.participant for rec in records}
    out = []
    for given in paths:
        listing_path = Path(given) / PULL_LISTING_FILE
        if not listing_path.is_file():
            continue
        try:
            listing = json.loads(listing_path.read_text(encoding="utf-8"))
            withdrawn = {str(w["participant"]) for w in listing.get("withdrawn", [])}
            listed = [str(p["participant"]) for p in listing["participants"]
                      if (p.get("session") or {}).get("n_ratings")]
        except (OSError, ValueError, KeyError, TypeError) as exc:
            out.append(InputProblem(str(listing_path), None,
                                    f"unreadable ({exc}); the sessions were not compared "
                                    "with the pull's list"))
            continue
        missing = [p for p in listed if p not in seen and p not in withdrawn]
        if missing:
            names = ", ".join(missing[:8]) + (", ..." if len(missing) > 8 else "")
            out.append(InputProblem(
                str(listing_path), None,
                f"the pull listed {len(missing)} participant(s) with ratings whose session "
                f"file is not in {given}: {names}; they are not in any number here (copy "
                "their files from the pull, or say in the paper why they are left out)"))
    return out


def read_one(source) -> Session:
    """One session source as a :class:`Session`; :class:`AnalysisError` when the file is not a
    readable session file."""
    name = source.origin
    try:
        rec = read_session(source.path)
    except (StudyError, OSError) as exc:
        raise AnalysisError(f"{name}: not used: {str(exc).replace(str(source.path), name)}") \
            from None
    info = rec.info
    problems = [InputProblem(name, p.row, p.message) for p in rec.problems]
    problems += [InputProblem(name, None, w.removeprefix(f"{name}: ")) for w in source.warnings]
    damaged = "; ".join(p.message for p in source.problems)
    return Session(path=name, info=info, ratings=list(rec.ratings),
                   presentations=list(rec.presentations), n_planned=int(rec.n_planned),
                   problems=problems, damaged=damaged, answers=list(rec.answers),
                   screenings=list(rec.screenings), events=list(rec.events),
                   name=source.name or name)


# -- deciding what belongs ------------------------------------------------------------------
@dataclass
class SessionSelection:
    """The sessions used, and everything refused or merged on the way."""

    used: list[Session]
    exclusions: list[Exclusion]
    problems: list[InputProblem]


def _withdrawals(records: list[Session], study_id: str) -> dict[str, str]:
    """Participant -> the (first) file in which they withdrew from this study. A withdrawal
    takes back consent for the participant, so it covers all their sessions."""
    out: dict[str, str] = {}
    for rec in sorted(records, key=lambda r: r.path):
        if rec.info.withdrawn and rec.info.study_id == study_id:
            out.setdefault(rec.info.participant, rec.path)
    return out


WITHDRAWAL_RULE = "a withdrawal covers every session of the participant"


def withdrawn_participants(exclusions: list[Exclusion]) -> list[str]:
    """The participants whose withdrawal refused their sessions (each once)."""
    out: list[str] = []
    for x in exclusions:
        rule, reason = (x.get("rule"), x.get("reason")) if isinstance(x, dict) else \
            (x.rule, x.reason)
        if rule == WITHDRAWAL_RULE and str(reason).startswith("participant "):
            who = str(reason).removeprefix("participant ").split(" withdrew", 1)[0]
            if who not in out:
                out.append(who)
    return out


def _deleted_exclusion(rec: Session, w: ServerWithdrawal) -> Exclusion:
    """The refusal of a copy of a session whose participant was withdrawn on the server."""
    return Exclusion("refused session", rec.path,
                     w.words() + ": this copy must not be used; delete it",
                     WITHDRAWAL_RULE)


def without_file(w: ServerWithdrawal) -> Exclusion:
    """A participant the listing names as withdrawn and of whom no file is left: counted
    among those who took part and withdrew."""
    return Exclusion("withdrawn participant", w.participant, w.words(),
                     WITHDRAWAL_RULE)


def _withdrawn_exclusion(rec: Session, withdrawn_in: str) -> Exclusion:
    """The refusal of one session of a participant who withdrew (this one or another)."""
    who = rec.info.participant
    if withdrawn_in == rec.path:
        reason = (f"participant {who} withdrew from the study in this session; none of their "
                  "sessions, ratings or answers is used")
    else:
        reason = (f"participant {who} withdrew from the study (in {withdrawn_in}); this "
                  "session of theirs is not used either")
    return Exclusion("refused session", rec.path, reason, WITHDRAWAL_RULE)


def _refusal(rec: Session, study_id: str, manifest_sha256: str | None,
             withdrawn: dict[str, str], twins: frozenset[str] = frozenset(),
             deleted: dict[str, ServerWithdrawal] | None = None) -> Exclusion | None:
    """Why ``rec`` is refused, or None when it belongs to the study."""
    if rec.damaged:
        return Exclusion("refused session", rec.path, f"{rec.damaged}; ask for the file again",
                         "session files must match the checksums of their export")
    if rec.info.study_id != study_id:
        return Exclusion(
            "refused session", rec.path,
            f"belongs to study {rec.info.study_id!r}, not to this manifest's study "
            f"{study_id!r}", "session study_id must equal the manifest's study_id")
    if deleted and rec.info.participant in deleted:
        return _deleted_exclusion(rec, deleted[rec.info.participant])
    if rec.info.participant in withdrawn:
        return _withdrawn_exclusion(rec, withdrawn[rec.info.participant])
    if manifest_sha256 and rec.info.manifest_sha256 in twins:
        return Exclusion(
            "refused session", rec.path,
            "was run with this manifest before its line endings were changed (by git or an "
            "upload, say): the content is the same, but sessions are matched to the file's "
            "exact bytes; analyse with the file the study was served with ('cgvq-study pull' "
            f"keeps it as manifest.{rec.info.manifest_sha256[:12]}.json), or convert its line "
            "endings back", "session manifest_sha256 must equal the manifest file's sha256")
    if manifest_sha256 and rec.info.manifest_sha256 and \
            rec.info.manifest_sha256 != manifest_sha256:
        return Exclusion(
            "refused session", rec.path,
            f"was run with another manifest (sha256 {rec.info.manifest_sha256[:12]}..., this "
            f"one is {manifest_sha256[:12]}...): the study changed after this session (init "
            "run again, say); analyse it with the manifest it ran on ('cgvq-study pull' keeps "
            f"a served study's earlier one as manifest.{rec.info.manifest_sha256[:12]}.json), "
            "or, for a pilot, pilot again",
            "session manifest_sha256 must equal the manifest file's sha256")
    return None


def is_pilot(rec: Session) -> bool:
    """A session the player paced on the clock (``--pilot-no-vsync``, ``--no-vsync``,
    ``--skip-preflight`` on a display without vsync): the experimenter's pilot or a test."""
    return "paced" in rec.timing_mode


def _pilot_exclusion(rec: Session) -> Exclusion:
    return Exclusion(
        "pilot session", rec.path,
        f"{rec.info.participant} ran without vsync, flips paced on the clock (timing mode "
        f"{rec.timing_mode}): an experimenter's pilot, not participant data",
        "paced sessions are left out when participant sessions are there too; "
        "--include-pilots keeps them")


def line_ending_twins(path: Path | None) -> frozenset[str]:
    """sha256 of the manifest file with its line endings converted (LF <-> CRLF): a session
    run with such a twin ran with the same content, which git or an upload re-encoded."""
    import hashlib

    if path is None or not Path(path).is_file():
        return frozenset()
    data = Path(path).read_bytes()
    lf = data.replace(b"\r\n", b"\n")
    return frozenset(hashlib.sha256(v).hexdigest() for v in (lf, lf.replace(b"\n", b"\r\n"))
                     if v != data)


def select_sessions(records: list[Session], study_id: str,
                    manifest_sha256: str | None, *,
                    include_pilots: bool = False,
                    twins: frozenset[str] = frozenset(),
                    deleted: dict[str, ServerWithdrawal] | None = None) -> SessionSelection:
    """Refuse withdrawn and foreign sessions, collapse copies of one session, and leave out
    pilots (paced, no vsync) when participant sessions are there too (unless
    ``include_pilots``): a pilot alone, or with simulated raters, is analysed as it is.
    ``twins``: :func:`line_ending_twins` of the manifest, named in the refusal;
    ``deleted``: :func:`session_store.pull_listing.server_withdrawals`, whose copies are
    refused and who are counted as withdrawn also when no file of theirs is left."""
    exclusions: list[Exclusion] = []
    problems: list[InputProblem] = []
    kept: list[Session] = []
    withdrawn = _withdrawals(records, study_id)
    for rec in sorted(records, key=lambda r: r.path):
        refused = _refusal(rec, study_id, manifest_sha256, withdrawn, twins, deleted)
        if refused is not None:
            exclusions.append(refused)
            continue
        if manifest_sha256 and not rec.info.manifest_sha256:
            problems.append(InputProblem(rec.path, None, "session records no manifest "
                                         "checksum; its study id matches, so it is used"))
        kept.append(rec)
    by_id: dict[str, list[Session]] = {}
    for rec in kept:
        by_id.setdefault(rec.info.session_id, []).append(rec)
    used: list[Session] = []
    for copies in by_id.values():
        copies.sort(key=lambda r: (-len(r.ratings), r.path))
        used.append(copies[0])
        for other in copies[1:]:
            exclusions.append(Exclusion(
                "duplicate session", other.path,
                f"another copy of session {other.info.session_id} (participant "
                f"{other.info.participant}); the copy with the most ratings, {copies[0].path}, "
                "is used", "one file per session id: most ratings, then file name"))
    used.sort(key=lambda r: r.order_key)
    if not include_pilots and any(not is_pilot(r) and r.timing_mode != "simulated"
                                  for r in used):
        exclusions += [_pilot_exclusion(r) for r in used if is_pilot(r)]
        used = [r for r in used if not is_pilot(r)]
    for rec in used:
        problems += rec.problems
    exclusions += [_ended_exclusion(rec) for rec in used if rec.ended_by]
    with_file = {rec.info.participant for rec in records}
    exclusions += [without_file(w) for pid, w in sorted((deleted or {}).items())
                   if pid not in with_file]
    return SessionSelection(used, exclusions, problems)


def _ended_exclusion(rec: Session) -> Exclusion:
    """A session the player closed after a failed vision check (``on_fail: end``): used for
    the panel's screening counts, listed so that the exclusions show who was not admitted."""
    n = len(rec.ratings)
    return Exclusion(
        "ended by vision check", rec.info.participant,
        f"the {rec.ended_by} check failed and ended their session ({rec.path}) after {n} "
        f"rating{'s' if n != 1 else ''}", "vision_screening.on_fail: end")
