"""Scoring every stimulus of a manifest with registry metrics into a scores CSV.

Work is cut into :class:`WorkUnit` objects, one per reference with all of its test videos:
paths, sha256s, metric names and options in, score rows out. A unit is self-contained (a
distributor can run it on another machine that sees the same files) and computes the
reference's features once for all of its tests. The driver (:func:`score_manifest`)
verifies every input's sha256 against the manifest before scoring (a truncated or edited
stimulus is an error, not a silent score), builds the units, skips rows already in the CSV
and appends the rows of each group of tests as it finishes (flushed), so an interrupted run
resumes and loses at most the group in progress.

Each row carries a resume ``key``: the sha256 of everything that changes its number (metric
name, its settings, backbone and weights hashes, patch scale, precision, device type,
pooling, implementation versions including cgvqm_core's and the sha256 of both input files).
Permissions (``--allow-resample``, ``--allow-convert``) are not in it: they decide whether a
pair is scored or refused, never its number, so adding one to resume after its error keeps
the rows already written. Keys written before that hashed the permissions too; they are
recognised (:func:`legacy_keys`). A row is skipped only when a row with the same key exists.
A file holds one row per (metric, pooling, stimulus): a run whose key for one of them differs
from the row already there (other settings, inputs or versions) is refused before any work, since
the analysis would keep only one of the two; write such runs to a new file.

Reading an existing file is strict about everything but its last row: a last row that was
torn by an interrupted write (no line end, or too few fields) is dropped with a warning and
cut off before the next rows are appended, so they never land on an unfinished line.
"""

from __future__ import annotations

import csv
import hashlib
import json
import logging
import os
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import IO, Any

from tqdm.auto import tqdm

from stimuli_manifests import StimuliError, load_manifest, sha256_path
from stimuli_manifests.file_lock import FileLock
from stimuli_manifests.pairs import same_frame_rate
from stimuli_manifests.tables import FORMAT_COLUMN, SCORES, SCORES_1_0, TableFormat

from .errors import CGVQMError
from .metrics.registry import MetricOptions, MetricScore, Scorer, build_scorers
from .metrics.viewing import ViewingCondition
from .progress import Progress, progress_bar

log = logging.getLogger(__name__)

#: provenance columns this toolkit adds after the contract's optional ones (names are stable)
EXTRA_COLUMNS = ("note", "reference_sha256", "stimulus_sha256", "versions", "key")
SCORE_COLUMNS = SCORES.header([*SCORES.optional, *EXTRA_COLUMNS])
#: the layouts a run may append to: this version's, and the one before ``title`` (1.0), whose
#: files a resumed run keeps in their own layout rather than refusing them
LAYOUTS: dict[tuple[str, ...], TableFormat] = {
    SCORE_COLUMNS: SCORES,
    SCORES_1_0.header([*SCORES_1_0.optional, *EXTRA_COLUMNS]): SCORES_1_0,
}


@dataclass(frozen=True)
class InputFile:
    """A video of a work unit: its manifest id, path and sha256."""

    id: str
    path: str
    sha256: str


@dataclass
class WorkUnit:
    """One reference and its test videos, to be scored with the named metrics."""

    reference_id: str
    reference: InputFile
    tests: list[InputFile]
    metrics: list[str]
    options: dict[str, Any]  # MetricOptions as plain data (see options_to_dict)
    allow_resample: bool = False
    on_conversion: str = "warn"
    group_size: int = 4
    strict: bool = False  # refuse a test whose frame count differs from the reference's

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> WorkUnit:
        d = dict(d)
        d["reference"] = InputFile(**d["reference"])
        d["tests"] = [InputFile(**t) for t in d["tests"]]
        return cls(**d)


def options_to_dict(o: MetricOptions) -> dict[str, Any]:
    d = asdict(o)
    d["viewing"] = {"display": o.viewing.display, "ppd": o.viewing.ppd}
    d["pools"] = list(o.pools)
    return d


def options_from_dict(d: dict[str, Any]) -> MetricOptions:
    d = dict(d)
    d["viewing"] = ViewingCondition(**d["viewing"])
    d["pools"] = tuple(d["pools"])
    d["learned_dirs"] = tuple(d.get("learned_dirs", ()))
    return MetricOptions(**d)


# -- keys and rows ------------------------------------------------------------------------

def canonical_json(obj: Any) -> str:
    """One JSON text per value (sorted keys, no spaces): what resume keys are hashes of."""
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), default=str)


def scorer_identity(s: Scorer, options: MetricOptions) -> dict[str, Any]:
    """What, besides the inputs and pooling, decides a scorer's numbers."""
    prov = s.provenance()
    return {"metric": s.name, "settings": s.settings(), "provenance": prov,
            "device_type": options.device.split(":")[0]}


def _key_of(doc: dict[str, Any]) -> str:
    return hashlib.sha256(canonical_json(doc).encode()).hexdigest()


def _key_doc(identity: dict[str, Any], pooling: str | None, ref: InputFile,
             test: InputFile) -> dict[str, Any]:
    return {**identity, "pooling": pooling or "", "reference": ref.id,
            "reference_sha256": ref.sha256, "stimulus": test.id, "stimulus_sha256": test.sha256}


def row_key(identity: dict[str, Any], pooling: str | None, ref: InputFile,
            test: InputFile) -> str:
    """The resume key of one row (stimulus and reference ids and contents included)."""
    return _key_of(_key_doc(identity, pooling, ref, test))


#: every value of the permissions that keys written before 2026-11-28 hashed
_LEGACY_PERMISSIONS = [{"allow_resample": a, "on_conversion": c}
                       for a in (False, True) for c in ("error", "warn")]


def legacy_keys(identity: dict[str, Any], pooling: str | None, ref: InputFile,
                test: InputFile) -> list[str]:
    """The keys the same row had when permissions were hashed in (``"alignment"``): such a
    row in an existing file counts as done, so an upgrade does not score it again."""
    doc = _key_doc(identity, pooling, ref, test)
    return [_key_of({**doc, "alignment": a}) for a in _LEGACY_PERMISSIONS]


def _poolings(s: Scorer, options: MetricOptions) -> list[str | None]:
    from .metrics.cgvqm_entry import CGVQMScorer

    return list(options.pools) if isinstance(s, CGVQMScorer) else [None]


def scorer_plan(scorers: Sequence[Scorer], options: MetricOptions
                ) -> list[tuple[dict[str, Any], list[str | None]]]:
    """Per scorer, its identity and the poolings it writes: with a unit's inputs, these give
    the keys of all of the unit's rows (plain data, so a worker can send them back)."""
    return [(scorer_identity(s, options), _poolings(s, options)) for s in scorers]


def unit_keys(unit: WorkUnit, plan: Sequence[tuple[dict[str, Any], list[str | None]]]
              ) -> list[str]:
    """The resume keys of every row ``unit`` writes (see :func:`scorer_plan`)."""
    return [row_key(ident, p, unit.reference, t)
            for t in unit.tests for ident, pools in plan for p in pools]


@dataclass(frozen=True)
class PlannedRow:
    """A row a run would write: its slot, its key and the keys it had in older files."""

    slot: Slot
    key: str
    legacy: tuple[str, ...]


def planned_rows(units: Sequence[WorkUnit],
                 plan: Sequence[tuple[dict[str, Any], list[str | None]]]) -> list[PlannedRow]:
    """Every row the units write."""
    return [PlannedRow((ident["metric"], p or "", t.id), row_key(ident, p, unit.reference, t),
                       tuple(legacy_keys(ident, p, unit.reference, t)))
            for unit in units for t in unit.tests for ident, pools in plan for p in pools]


def done_keys(state: ScoresFile, planned: Sequence[PlannedRow]) -> set[str]:
    """The keys of the file's rows, plus the key of each planned row that the file holds
    under a legacy key (see :func:`legacy_keys`)."""
    done = set(state.keys)
    done.update(r.key for r in planned if not done.isdisjoint(r.legacy))
    return done


def _row(stimulus: str, reference: str, m: MetricScore, ident: dict[str, Any], key: str,
         ref_sha: str, test_sha: str, title: str) -> dict[str, Any]:
    settings = dict(ident["settings"])
    settings["device_type"] = ident["device_type"]
    prov = {k: v for k, v in ident["provenance"].items()
            if k not in ("backbone", "backbone_sha256", "weights_sha256")}
    return {
        "stimulus": stimulus, "reference": reference, "metric": m.metric,
        "title": title,  # not in the key: a renamed title must not rescore anything
        "score": "" if m.score is None else f"{m.score:.8g}", "direction": m.direction,
        "pooling": m.pooling or "", "patches": m.extra.get("patches", ""),
        "seconds": f"{m.extra['seconds']:.3f}" if "seconds" in m.extra else "",
        # a scorer's hashes come with each result (CGVQM) or from its provenance (peers)
        **{k: m.extra.get(k, ident["provenance"].get(k, ""))
           for k in ("backbone", "backbone_sha256", "weights_sha256")},
        "settings": canonical_json(settings), "note": m.note,
        "reference_sha256": ref_sha, "stimulus_sha256": test_sha,
        "versions": canonical_json(prov), "key": key,
    }


# -- the scores file ------------------------------------------------------------------------

Slot = tuple[str, str, str]  # (metric, pooling, stimulus): one row per slot in a file


@dataclass
class ScoresFile:
    """What an existing scores CSV holds: its rows' keys, the key(s) of each slot, and how
    many of its bytes are complete rows (a torn last row beyond them is cut off on append)."""

    path: Path
    keys: set[str] = field(default_factory=set)
    slots: dict[Slot, set[str]] = field(default_factory=dict)
    size: int = 0
    #: the file's columns and contract (rows appended to it keep them)
    columns: tuple[str, ...] = SCORE_COLUMNS
    layout: TableFormat = SCORES

    def add(self, row: dict[str, Any]) -> None:
        """Record a row written in this run."""
        self.keys.add(row.get("key", ""))
        self.slots.setdefault(slot_of(row), set()).add(row.get("key", ""))

    def clashes(self, slot: Slot, key: str, done: set[str] | None = None) -> bool:
        """Would a row with ``key`` in ``slot`` be a second row there? ``done``: keys that
        count as present (:func:`done_keys`). An empty key, as ``score --csv`` writes, never
        matches: such rows cannot be told equal."""
        held = self.slots.get(slot)
        return held is not None and (not key or key not in (held if done is None else done))


def slot_of(row: dict[str, Any]) -> Slot:
    return (str(row.get("metric", "")), str(row.get("pooling") or ""),
            str(row.get("stimulus", "")))


def _describe(slot: Slot) -> str:
    metric, pooling, stimulus = slot
    return f"{metric}{f' ({pooling})' if pooling else ''} for {stimulus}"


def refuse_clashes(state: ScoresFile, planned: Sequence[PlannedRow], flag: str,
                   done: set[str] | None = None) -> None:
    """Refuse rows that would be a second row of their slot (see :meth:`ScoresFile.clashes`)."""
    bad = [r.slot for r in planned if state.clashes(r.slot, r.key, done)]
    if bad:
        more = f" and {len(bad) - 1} more" if len(bad) > 1 else ""
        raise CGVQMError(
            f"{state.path}: already holds a score of {_describe(bad[0])}{more} computed with "
            "other settings, inputs or versions (another resume key); a second row would be "
            f"ignored by the analysis: use a new {flag} (or remove those rows)")


def _unreadable(path: Path, why: str, flag: str) -> CGVQMError:
    return CGVQMError(f"{path}: {why}; it is not a scores CSV this toolkit wrote: choose "
                      f"another {flag}")


def _lines(path: Path, flag: str) -> list[str]:
    """The file's lines (ends kept); a folder or a file that is not UTF-8 text is refused."""
    if path.is_dir():
        raise CGVQMError(f"{flag} {path}: is a folder; give a scores file name (.csv)")
    try:
        text = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise _unreadable(path, f"not UTF-8 text (byte {exc.start}: {exc.reason})",
                          flag) from None
    except OSError as exc:
        raise CGVQMError(f"{flag} {path}: cannot be read ({exc.strerror or exc})") from None
    parts = text.split("\n")  # only \n ends a line here (csv writes \r\n)
    return [x + "\n" for x in parts[:-1]] + ([parts[-1]] if parts[-1] else [])


def _parse(path: Path, lines: list[str], flag: str) -> tuple[list[list[str]], list[int]]:
    """CSV rows and the line index each starts at (csv.Error refused in one line)."""
    rows: list[list[str]] = []
    starts: list[int] = []
    reader = csv.reader(iter(lines))
    try:
        while True:
            start = reader.line_num
            try:
                row = next(reader)
            except StopIteration:
                break
            rows.append(row)
            starts.append(start)
    except csv.Error as exc:
        raise _unreadable(path, f"unparsable CSV at line {reader.line_num} ({exc})",
                          flag) from None
    return rows, starts


def read_scores(path: str | Path, *, flag: str = "--out") -> ScoresFile:
    """Read an existing scores CSV (a missing or empty one holds nothing).

    Refused in one line: a folder, a file that is not UTF-8 or not CSV, another layout, a
    damaged row inside. A torn last row is dropped with a warning (see the module doc)."""
    path = Path(path)
    state = ScoresFile(path)
    if not path.exists():
        return state
    lines = _lines(path, flag)
    if not lines:
        return state
    if len(lines) == 1 and not lines[0].endswith("\n") and any(
            ",".join(columns).startswith(lines[0]) for columns in LAYOUTS):
        log.warning("%s: its header line is unfinished (an interrupted write); it is "
                    "written again", path)
        return state
    rows, starts = _parse(path, lines, flag)
    header = tuple(rows[0]) if rows else ()
    if header not in LAYOUTS:
        raise CGVQMError(f"{path}: existing file has columns {', '.join(header)}, not this "
                         f"toolkit's scores layout ({SCORES.version}: "
                         f"{', '.join(SCORE_COLUMNS)}); choose another {flag}")
    state.columns, state.layout = header, LAYOUTS[header]
    complete = len(rows)
    last_torn = not lines[-1].endswith("\n") or len(rows[-1]) != len(header)
    if complete > 1 and last_torn and rows[-1]:
        complete -= 1
        log.warning("%s: its last row (line %d) is unfinished, torn by an interrupted write; "
                    "it is dropped and scored again", path, starts[-1] + 1)
    data = [r for r in rows[1:complete] if r]  # blank lines hold nothing
    bad = next((i for i, r in enumerate(rows[1:complete], start=2)
                if r and len(r) != len(header)), None)
    if bad is not None:
        raise _unreadable(path, f"row {bad} has {len(rows[bad - 1])} fields, not "
                                f"{len(header)} (damaged)", flag)
    kept = lines[: starts[complete]] if complete < len(rows) else lines
    state.size = sum(len(x.encode("utf-8")) for x in kept)
    records = [dict(zip(header, r, strict=True)) for r in data]
    state.layout.check(header, [r.get(FORMAT_COLUMN) for r in records], path)
    for r in records:
        state.add(r)
    return state


def read_done(path: Path, *, flag: str = "--out") -> set[str]:
    """Resume keys of the rows already in ``path`` (refuses a file of another layout)."""
    return read_scores(path, flag=flag).keys


class _ScoresLock(FileLock):
    error = CGVQMError


def scores_lock(path: str | Path, *, flag: str = "--out") -> FileLock:
    """One writer per scores CSV, held from reading it (what is done, which slots are
    taken) to the last row: two runs on one file each trusted what they had read, and one cut
    the other's rows off as a "torn tail"."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    return _ScoresLock(path, "cgvqm", busy=lambda holder: (
        f"{flag} {path}: another cgvqm run is writing it{holder}; wait for it to finish, or "
        f"give another {flag} (one run per scores CSV at a time)"))


class Appender:
    """Appends rows to a scores CSV (header first if new), flushed to disk per write. The
    file is created with the first rows, so a run that fails before scoring anything leaves
    no header-only CSV behind for the next step to read as an empty result.

    ``state`` is what :func:`read_scores` found (read here when not given): a torn last row
    beyond its complete rows is cut off before the first write, and a row that would be a
    second row of its (metric, pooling, stimulus) is refused."""

    def __init__(self, path: Path, state: ScoresFile | None = None, *,
                 flag: str = "--out") -> None:
        self.path = path
        self.flag = flag
        self.state = state
        self.fh: IO[str] | None = None
        self.writer: Any = None

    def _open(self) -> None:
        if self.state is None:
            self.state = read_scores(self.path, flag=self.flag)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if self.path.is_file() and self.path.stat().st_size > self.state.size:
            with self.path.open("r+b") as fh:  # drop the torn tail read_scores found
                fh.truncate(self.state.size)
        new = not self.path.is_file() or self.path.stat().st_size == 0
        if not new:
            with self.path.open("rb") as fh:
                fh.seek(-1, os.SEEK_END)
                unfinished = fh.read(1) != b"\n"
        self.fh = self.path.open("a", newline="", encoding="utf-8")
        self.writer = csv.writer(self.fh)
        if new:
            self.state.columns, self.state.layout = SCORE_COLUMNS, SCORES
            self.writer.writerow(SCORE_COLUMNS)
        elif unfinished:  # never glue a row onto another one
            self.fh.write("\r\n")

    def write(self, rows: list[dict[str, Any]]) -> None:
        if not rows:
            return
        if self.fh is None:
            self._open()
        assert self.state is not None
        refuse_clashes(self.state, [PlannedRow(slot_of(r), r.get("key", ""), ()) for r in rows],
                       self.flag)
        version = self.state.layout.version  # an older file keeps its layout and version
        self.writer.writerows([[version if c == FORMAT_COLUMN else r.get(c, "")
                                for c in self.state.columns] for r in rows])
        self.flush()
        for r in rows:
            self.state.add(r)

    def flush(self) -> None:
        if self.fh is not None:
            self.fh.flush()
            os.fsync(self.fh.fileno())

    def close(self) -> None:
        if self.fh is not None:
            self.fh.close()


# -- running a unit -------------------------------------------------------------------------

def verify_inputs(files: Sequence[InputFile]) -> None:
    """Refuse files whose content is not the sha256 they are said to have."""
    bad = []
    for f in files:
        try:
            actual = sha256_path(f.path)
        except StimuliError as exc:
            raise CGVQMError(str(exc)) from None
        if actual != f.sha256:
            bad.append(f"{f.id}: {f.path} has sha256 {actual[:12]}..., expected "
                       f"{f.sha256[:12]}...")
    if bad:
        raise CGVQMError(f"{len(bad)} input(s) differ from the manifest's sha256 (changed, "
                         f"truncated or replaced; fix or re-checksum the manifest): "
                         + "; ".join(bad[:5]))


def _result_of(per_test: Sequence[MetricScore], name: str, pooling: str | None
               ) -> MetricScore:
    """A scorer's result among a test's, by metric name and pooling, not by position: the
    image-metric pass lists metrics that do not apply at a size first, so position would
    give a row another metric's resume key."""
    for m in per_test:
        if m.metric == name and (pooling is None or m.pooling == pooling):
            return m
    raise CGVQMError(f"no {name}{f' ({pooling})' if pooling else ''} result among "
                     f"{', '.join(m.metric for m in per_test)}")


def run_unit(unit: WorkUnit, *, scorers: Sequence[Scorer] | None = None,
             done: set[str] | frozenset[str] = frozenset(), verify: bool = True,
             progress: bool = False,
             on_group: Callable[[int], None] | None = None,
             on_rows: Callable[[list[dict[str, Any]]], None] | None = None
             ) -> list[dict[str, Any]]:
    """Score a unit's tests whose rows are not in ``done``; return the new rows.

    ``scorers`` may be given when the caller already built them (same options); a remote
    worker builds them from ``unit.options``. ``on_rows(rows)`` receives each group's rows
    as soon as the group is scored (so a local driver can append them before the next
    group: an interrupt then loses only the group in progress), then ``on_group(n)`` is
    called with the group's number of tests (progress).
    """
    from .metrics.engine import score_reference

    options = options_from_dict(unit.options)
    if scorers is None:
        scorers = build_scorers(unit.metrics, options)
    if verify:
        verify_inputs([unit.reference, *unit.tests])
    idents = [scorer_identity(s, options) for s in scorers]
    ref_sha = unit.reference.sha256
    plan: dict[int, list[int]] = {}  # test index -> scorer indices with a missing row
    for ti, t in enumerate(unit.tests):
        for si, s in enumerate(scorers):
            keys = [row_key(idents[si], p, unit.reference, t)
                    for p in _poolings(s, options)]
            if any(k not in done for k in keys):
                plan.setdefault(ti, []).append(si)
    rows: list[dict[str, Any]] = []
    pending = sorted(plan)
    size = max(1, unit.group_size)
    for g in range(0, len(pending), size):
        group = pending[g: g + size]
        used = sorted({si for ti in group for si in plan[ti]})
        results = score_reference(unit.reference.path, [unit.tests[ti].path for ti in group],
                                  [scorers[si] for si in used], device=options.device,
                                  allow_resample=unit.allow_resample,
                                  on_conversion=unit.on_conversion, progress=progress,
                                  strict=unit.strict)
        group_rows: list[dict[str, Any]] = []
        for ti, per_test in zip(group, results, strict=True):
            t = unit.tests[ti]
            for si in used:
                for p in _poolings(scorers[si], options):
                    m = _result_of(per_test, scorers[si].name, p)
                    key = row_key(idents[si], p, unit.reference, t)
                    if key not in done:
                        group_rows.append(_row(t.id, unit.reference_id, m, idents[si], key,
                                               ref_sha, t.sha256, scorers[si].title))
        rows += group_rows
        if on_rows is not None:
            on_rows(group_rows)
        if on_group is not None:
            on_group(len(group))
    return rows


# -- the driver -----------------------------------------------------------------------------

@dataclass
class BatchSummary:
    scored: int = 0  # test videos scored (with at least one metric)
    skipped: int = 0  # test videos whose rows were all present
    rows: int = 0  # rows written
    not_applicable: list[str] = field(default_factory=list)


def _load(manifest: str | Path, root: str | Path | None) -> Any:
    try:
        return load_manifest(manifest, root=root)
    except StimuliError as exc:
        raise CGVQMError(str(exc)) from None


def refuse_misaligned_pairs(manifest: str | Path, *, include_references: bool = False,
                            root: str | Path | None = None, on_conversion: str = "warn",
                            allow_resample: bool = False, strict: bool = False) -> None:
    """Before any network is built or file hashed, probe every pair (headers only) and
    refuse the run, naming up to five, when a video cannot be opened (or needs a conversion
    not allowed), a test's frame rate differs from its reference's without
    ``allow_resample``, or (``strict``) its frame count does. Found mid-run instead, the
    first such pair stopped a batch after hours of work."""
    from .stream import open_input

    loaded = _load(manifest, root)
    opened: dict[Path, Any] = {}
    unreadable, rates, counts = [], [], []

    def probe(path: Path, name: str) -> Any:
        if path not in opened:
            try:
                opened[path] = open_input(path, name=name, on_conversion=on_conversion)
            except CGVQMError as exc:
                opened[path] = None
                unreadable.append(str(exc))
        return opened[path]

    for s in loaded.manifest.stimuli(include_hidden_references=include_references):
        ref = probe(loaded.reference_path(s.reference), s.reference)
        test = probe(loaded.stimulus_path(s.id), s.id)
        if ref is None or test is None:
            continue
        fr, ft = float(ref.info.fps), float(test.info.fps)
        if not allow_resample and not same_frame_rate(fr, ft):
            rates.append(f"{s.id} is at {ft:g} fps, its reference {s.reference} at {fr:g}")
        nr, nt = int(ref.info.frame_count), int(test.info.frame_count)
        if strict and nr != nt:
            counts.append(f"{s.id} has {nt} frames, its reference {s.reference} {nr}")
    if unreadable:
        raise CGVQMError(f"{len(unreadable)} video(s) of the manifest cannot be scored: "
                         f"{_first_five(unreadable)}")
    if rates:
        raise CGVQMError(f"{len(rates)} test video(s) differ from their reference in frame "
                         f"rate ({_first_five(rates)}); pass --allow-resample to resample them "
                         "to the reference's frame count as the authors' code does, or "
                         "re-render them")
    if counts:
        raise CGVQMError(f"--strict: {len(counts)} test video(s) differ from their reference "
                         f"in frame count ({_first_five(counts)}); without --strict they are "
                         "resampled in time (frames repeated or dropped); trim or re-render "
                         "them")


def _first_five(items: list[str]) -> str:
    return "; ".join(items[:5]) + ("; ..." if len(items) > 5 else "")


def manifest_units(manifest: str | Path, metrics: Sequence[str], options: MetricOptions, *,
                   include_references: bool = False, root: str | Path | None = None,
                   group_size: int = 4, allow_resample: bool = False,
                   on_conversion: str = "warn", progress: Progress = True,
                   strict: bool = False) -> list[WorkUnit]:
    """One work unit per reference, after checking every input's sha256."""
    loaded = _load(manifest, root)
    stimuli = loaded.manifest.stimuli(include_hidden_references=include_references)
    if not stimuli:
        raise CGVQMError(f"{manifest}: lists no test videos to score (no conditions"
                         + ("" if include_references else "; hidden references are scored "
                            "only with --include-references") + ")")
    by_ref: dict[str, list[Any]] = {}
    for s in stimuli:
        by_ref.setdefault(s.reference, []).append(s)
    paths: dict[str, tuple[Path, str | None]] = {}
    for ref_id in by_ref:
        paths[ref_id] = (loaded.reference_path(ref_id),
                         loaded.manifest.reference_by_id(ref_id).sha256)
    for s in stimuli:
        paths.setdefault(s.id, (loaded.stimulus_path(s.id), s.sha256))
    digests: dict[str, str] = {}
    bad = []
    for sid, (path, expected) in tqdm(paths.items(), desc="checking inputs", unit="file",
                                      disable=progress is not True, leave=False):
        try:
            actual = sha256_path(path)
        except StimuliError as exc:
            raise CGVQMError(str(exc)) from None
        if expected is not None and actual != expected:
            bad.append(f"{sid}: {path} has sha256 {actual[:12]}..., the manifest records "
                       f"{expected[:12]}...")
        digests[sid] = actual
    if bad:
        raise CGVQMError(f"{len(bad)} stimulus file(s) differ from the manifest's sha256 "
                         "(changed, truncated or replaced; restore them or re-checksum the "
                         "manifest): " + "; ".join(bad[:5]))
    units = []
    opts = options_to_dict(options)
    for ref_id, group in by_ref.items():
        ref = InputFile(ref_id, str(paths[ref_id][0]), digests[ref_id])
        tests = [InputFile(s.id, str(paths[s.id][0]), digests[s.id]) for s in group]
        units.append(WorkUnit(ref_id, ref, tests, list(metrics), opts, allow_resample,
                              on_conversion, group_size, strict))
    return units


def score_manifest(manifest: str | Path, out: str | Path, metrics: Sequence[str],
                   options: MetricOptions | None = None, *, include_references: bool = False,
                   root: str | Path | None = None, group_size: int = 4,
                   allow_resample: bool = False, on_conversion: str = "warn",
                   progress: Progress = True, strict: bool = False) -> BatchSummary:
    """Score the manifest's conditions (and hidden references if asked) with each metric.

    Every pair's headers are checked first (:func:`refuse_misaligned_pairs`): a frame-rate
    mismatch is refused unless ``allow_resample``; ``strict`` refuses a frame-count mismatch,
    which is otherwise resampled in time."""
    with scores_lock(out):
        return _score_manifest(manifest, Path(out), metrics, options or MetricOptions(),
                               include_references=include_references, root=root,
                               group_size=group_size, allow_resample=allow_resample,
                               on_conversion=on_conversion, progress=progress, strict=strict)


def _score_manifest(manifest: str | Path, out: Path, metrics: Sequence[str],
                    options: MetricOptions, *, include_references: bool,
                    root: str | Path | None, group_size: int, allow_resample: bool,
                    on_conversion: str, progress: Progress, strict: bool) -> BatchSummary:
    state = read_scores(out)
    refuse_misaligned_pairs(manifest, include_references=include_references, root=root,
                            on_conversion=on_conversion, allow_resample=allow_resample,
                            strict=strict)
    scorers = build_scorers(metrics, options)
    units = manifest_units(manifest, metrics, options, include_references=include_references,
                           root=root, group_size=group_size, allow_resample=allow_resample,
                           on_conversion=on_conversion, progress=progress, strict=strict)
    planned = planned_rows(units, scorer_plan(scorers, options))
    done = done_keys(state, planned)
    refuse_clashes(state, planned, "--out", done)
    summary = BatchSummary()
    total = sum(len(u.tests) for u in units)
    appender = Appender(out, state)
    bar = progress_bar(total, "cgvqm batch", "video", progress)
    try:
        for u in units:
            rows = run_unit(u, scorers=scorers, done=done, verify=False,
                            on_group=bar.update, on_rows=appender.write)
            scored = {r["stimulus"] for r in rows}
            summary.scored += len(scored)
            summary.skipped += len(u.tests) - len(scored)
            summary.rows += len(rows)
            for r in rows:
                done.add(r["key"])
                if r["note"] and not r["score"] and r["metric"] not in summary.not_applicable:
                    summary.not_applicable.append(r["metric"])
            bar.update(len(u.tests) - len(scored))  # the skipped ones
    finally:
        bar.close()
        appender.close()
    return summary
