"""Scoring every stimulus of a manifest with registry metrics into a scores CSV.

Work is cut into :class:`WorkUnit` objects, one per reference with all of its test videos:
paths, sha256s, metric names and options in, score rows out. A unit is self-contained (a
distributor can run it on another machine that sees the same files) and computes the
reference's features once for all of its tests. The driver (:func:`score_manifest`)
verifies every input's sha256 against the manifest before scoring (a truncated or edited
stimulus is an error, not a silent score), builds the units, skips rows already in the CSV
and appends each unit's rows as it finishes (flushed), so an interrupted run resumes.

Each row carries a resume ``key``: the sha256 of everything that changes its number (metric
name, its settings, backbone and weights hashes, patch scale, precision, device type,
pooling, implementation versions, alignment options and the sha256 of both input files). A
row is skipped only when a row with the same key exists; change anything and it is scored
again (the old row stays, and the analysis keeps the first one of a metric and stimulus, so
write to a new file when settings change).
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
from stimuli_manifests.tables import FORMAT_COLUMN, SCORES

from .errors import CGVQMError
from .metrics.registry import MetricOptions, MetricScore, Scorer, build_scorers
from .metrics.viewing import ViewingCondition

log = logging.getLogger(__name__)

#: provenance columns this toolkit adds after the contract's optional ones (names are stable)
EXTRA_COLUMNS = ("note", "reference_sha256", "stimulus_sha256", "versions", "key")
SCORE_COLUMNS = SCORES.header([*SCORES.optional, *EXTRA_COLUMNS])


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


def row_key(identity: dict[str, Any], pooling: str | None, ref: InputFile, test: InputFile,
            alignment: dict[str, Any]) -> str:
    """The resume key of one row (stimulus and reference ids and contents included)."""
    doc = {**identity, "pooling": pooling or "", "reference": ref.id,
           "reference_sha256": ref.sha256, "stimulus": test.id, "stimulus_sha256": test.sha256,
           "alignment": alignment}
    return hashlib.sha256(canonical_json(doc).encode()).hexdigest()


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
    alignment = {"allow_resample": unit.allow_resample, "on_conversion": unit.on_conversion}
    return [row_key(ident, p, unit.reference, t, alignment)
            for t in unit.tests for ident, pools in plan for p in pools]


def _row(stimulus: str, reference: str, m: MetricScore, ident: dict[str, Any], key: str,
         ref_sha: str, test_sha: str) -> dict[str, Any]:
    settings = dict(ident["settings"])
    settings["device_type"] = ident["device_type"]
    prov = {k: v for k, v in ident["provenance"].items()
            if k not in ("backbone", "backbone_sha256", "weights_sha256")}
    return {
        "stimulus": stimulus, "reference": reference, "metric": m.metric,
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

def read_done(path: Path) -> set[str]:
    """Resume keys of the rows already in ``path`` (refuses a file of another layout)."""
    if not path.is_file() or path.stat().st_size == 0:
        return set()
    with path.open(newline="", encoding="utf-8") as fh:
        reader = csv.DictReader(fh)
        header = tuple(reader.fieldnames or ())
        if header != SCORE_COLUMNS:
            raise CGVQMError(f"{path}: existing file has columns {', '.join(header)}, not this "
                             f"toolkit's scores layout ({SCORES.version}: "
                             f"{', '.join(SCORE_COLUMNS)}); choose another --out")
        rows = list(reader)
    SCORES.check(header, [r.get(FORMAT_COLUMN) for r in rows], path)
    return {r["key"] for r in rows}


class Appender:
    """Appends rows to a scores CSV (header first if new), flushed to disk per write. The
    file is created with the first rows, so a run that fails before scoring anything leaves
    no header-only CSV behind for the next step to read as an empty result."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.fh: IO[str] | None = None
        self.writer: Any = None

    def _open(self) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        new = not self.path.is_file() or self.path.stat().st_size == 0
        self.fh = self.path.open("a", newline="", encoding="utf-8")
        self.writer = csv.writer(self.fh)
        if new:
            self.writer.writerow(SCORE_COLUMNS)

    def write(self, rows: list[dict[str, Any]]) -> None:
        if not rows:
            return
        if self.fh is None:
            self._open()
        self.writer.writerows([[SCORES.version if c == FORMAT_COLUMN else r.get(c, "")
                                for c in SCORE_COLUMNS] for r in rows])
        self.flush()

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


def run_unit(unit: WorkUnit, *, scorers: Sequence[Scorer] | None = None,
             done: set[str] | frozenset[str] = frozenset(), verify: bool = True,
             progress: bool = False,
             on_group: Callable[[int], None] | None = None) -> list[dict[str, Any]]:
    """Score a unit's tests whose rows are not in ``done``; return the new rows.

    ``scorers`` may be given when the caller already built them (same options); a remote
    worker builds them from ``unit.options``. ``on_group(n)`` is called after each group of
    ``n`` tests (progress).
    """
    from .metrics.engine import score_reference

    options = options_from_dict(unit.options)
    if scorers is None:
        scorers = build_scorers(unit.metrics, options)
    if verify:
        verify_inputs([unit.reference, *unit.tests])
    alignment = {"allow_resample": unit.allow_resample, "on_conversion": unit.on_conversion}
    idents = [scorer_identity(s, options) for s in scorers]
    ref_sha = unit.reference.sha256
    plan: dict[int, list[int]] = {}  # test index -> scorer indices with a missing row
    for ti, t in enumerate(unit.tests):
        for si, s in enumerate(scorers):
            keys = [row_key(idents[si], p, unit.reference, t, alignment)
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
        for ti, per_test in zip(group, results, strict=True):
            t = unit.tests[ti]
            it = iter(per_test)
            for si in used:
                for p in _poolings(scorers[si], options):
                    m = next(it)
                    key = row_key(idents[si], p, unit.reference, t, alignment)
                    if key not in done:
                        rows.append(_row(t.id, unit.reference_id, m, idents[si], key,
                                         ref_sha, t.sha256))
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


def refuse_frame_count_mismatches(manifest: str | Path, *, include_references: bool = False,
                                  root: str | Path | None = None,
                                  on_conversion: str = "warn") -> None:
    """``--strict``: refuse the run, before any network is built or file hashed, when a test
    video's frame count differs from its reference's (every such pair is probed, headers only,
    and up to five are named)."""
    from .stream import open_input

    loaded = _load(manifest, root)
    refs: dict[str, Any] = {}
    bad = []
    for s in loaded.manifest.stimuli(include_hidden_references=include_references):
        if s.reference not in refs:
            refs[s.reference] = open_input(loaded.reference_path(s.reference),
                                           name=s.reference, on_conversion=on_conversion)
        ref = refs[s.reference]
        test = open_input(loaded.stimulus_path(s.id), name=s.id, on_conversion=on_conversion)
        nr, nt = int(ref.info.frame_count), int(test.info.frame_count)
        if nr != nt:
            bad.append(f"{s.id} has {nt} frames, its reference {s.reference} {nr}")
    if bad:
        raise CGVQMError(f"--strict: {len(bad)} test video(s) differ from their reference in "
                         f"frame count ({'; '.join(bad[:5])}{'; ...' if len(bad) > 5 else ''})"
                         "; without --strict they are resampled in time (frames repeated or "
                         "dropped); trim or re-render them")


def manifest_units(manifest: str | Path, metrics: Sequence[str], options: MetricOptions, *,
                   include_references: bool = False, root: str | Path | None = None,
                   group_size: int = 4, allow_resample: bool = False,
                   on_conversion: str = "warn", progress: bool = True,
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
                                      disable=not progress, leave=False):
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
                   progress: bool = True, strict: bool = False) -> BatchSummary:
    """Score the manifest's conditions (and hidden references if asked) with each metric.

    ``strict`` refuses the run when any test's frame count differs from its reference's
    (checked first, from the headers); otherwise such a test is resampled in time."""
    options = options or MetricOptions()
    out = Path(out)
    done = read_done(out)
    if strict:
        refuse_frame_count_mismatches(manifest, include_references=include_references,
                                      root=root, on_conversion=on_conversion)
    scorers = build_scorers(metrics, options)
    units = manifest_units(manifest, metrics, options, include_references=include_references,
                           root=root, group_size=group_size, allow_resample=allow_resample,
                           on_conversion=on_conversion, progress=progress, strict=strict)
    summary = BatchSummary()
    total = sum(len(u.tests) for u in units)
    appender = Appender(out)
    bar = tqdm(total=total, desc="cgvqm batch", unit="video", disable=not progress)
    try:
        for u in units:
            rows = run_unit(u, scorers=scorers, done=done, verify=False, on_group=bar.update)
            appender.write(rows)
            scored = {r["stimulus"] for r in rows}
            summary.scored += len(scored)
            summary.skipped += len(u.tests) - len(scored)
            summary.rows += len(rows)
            for r in rows:
                done.add(r["key"])
                if r["note"] and r["metric"] not in summary.not_applicable:
                    summary.not_applicable.append(r["metric"])
            bar.update(len(u.tests) - len(scored))  # the skipped ones
    finally:
        bar.close()
        appender.close()
    return summary
