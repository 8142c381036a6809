"""Scoring every stimulus of a manifest into a scores CSV (DESIGN.md contract 4).

Conditions are grouped by reference so that each reference goes through the network once
per patch for all its conditions. The CSV is appended to one group at a time and flushed,
so an interrupted run resumes where it stopped: rows already present for (stimulus, metric,
pooling) are skipped. Several variants and poolings can share one file.
"""

from __future__ import annotations

import csv
import logging
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tqdm.auto import tqdm

from stimuli_manifests import StimuliError, load_manifest

from .errors import CGVQMError
from .metric import CGVQM, POOLINGS

log = logging.getLogger(__name__)

SCORE_COLUMNS = ("stimulus", "reference", "metric", "score", "pooling", "patches", "seconds",
                 "backbone", "backbone_sha256", "weights_sha256")


@dataclass
class BatchSummary:
    scored: int = 0  # stimulus x variant pairs computed
    skipped: int = 0  # already in the CSV
    rows: int = 0  # rows written


def metric_name(metric: CGVQM) -> str:
    """``cgvqm-2`` / ``cgvqm-5`` for the published weights; other weights get a suffix, and
    seamless tiling (not upstream-identical) adds ``-seamless``."""
    w = metric.weights
    if w.kind == "upstream-pickle":
        name = metric.variant
    elif w.kind == "uniform":
        name = f"{metric.variant}-uniform"
    else:
        name = f"{metric.variant}-{Path(w.source).stem}"
    return f"{name}-seamless" if metric.seamless else name


def read_done(path: Path) -> set[tuple[str, str, str]]:
    """(stimulus, metric, pooling) of every row already in ``path``."""
    if not path.is_file() or path.stat().st_size == 0:
        return set()
    with path.open(newline="", encoding="utf-8") as fh:
        reader = csv.DictReader(fh)
        header = tuple(reader.fieldnames or ())
        if header != SCORE_COLUMNS:
            raise CGVQMError(f"{path}: existing file has columns {', '.join(header)}, not the "
                             f"scores contract ({', '.join(SCORE_COLUMNS)}); choose another --out")
        return {(r["stimulus"], r["metric"], r["pooling"]) for r in reader}


class Appender:
    """Appends rows to a scores CSV (header first if new), flushed to disk per write."""

    def __init__(self, path: Path) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        new = not path.is_file() or path.stat().st_size == 0
        self.fh = path.open("a", newline="", encoding="utf-8")
        self.writer = csv.writer(self.fh)
        if new:
            self.writer.writerow(SCORE_COLUMNS)
            self.flush()

    def write(self, rows: list[list[Any]]) -> None:
        self.writer.writerows(rows)
        self.flush()

    def flush(self) -> None:
        self.fh.flush()
        os.fsync(self.fh.fileno())

    def close(self) -> None:
        self.fh.close()


def score_manifest(manifest: str | Path, out: str | Path, metrics: Sequence[CGVQM], *,
                   pools: Sequence[str] = ("max",), include_references: bool = False,
                   root: str | Path | None = None, group_size: int = 4,
                   allow_resample: bool = False, on_conversion: str = "warn",
                   progress: bool = True) -> BatchSummary:
    """Score the manifest's conditions (and hidden references if asked) with each metric."""
    for p in pools:
        if p not in POOLINGS:
            raise CGVQMError(f"unknown pooling {p!r}; choose max or mean")
    try:
        loaded = load_manifest(manifest, root=root)
    except StimuliError as exc:
        raise CGVQMError(str(exc)) from None
    stimuli = [s for s in loaded.manifest.stimuli(include_hidden_references=include_references)]
    out = Path(out)
    done = read_done(out)
    summary = BatchSummary()
    todo: list[tuple[CGVQM, str, str, list[Any]]] = []
    by_ref: dict[str, list[Any]] = {}
    for s in stimuli:
        by_ref.setdefault(s.reference, []).append(s)
    for m in metrics:
        name = metric_name(m)
        for ref_id, group in by_ref.items():
            pending = [s for s in group if any((s.id, name, p) not in done for p in pools)]
            summary.skipped += len(group) - len(pending)
            if pending:
                todo.append((m, name, ref_id, pending))
    total = sum(len(t[3]) for t in todo)
    appender = Appender(out)
    bar = tqdm(total=total, desc="cgvqm batch", unit="video", disable=not progress)
    try:
        for m, name, ref_id, pending in todo:
            ref_path = loaded.reference_path(ref_id)
            for i in range(0, len(pending), max(1, group_size)):
                chunk = pending[i: i + max(1, group_size)]
                paths = [loaded.stimulus_path(s.id) for s in chunk]
                results = m.score_many(ref_path, paths, allow_resample=allow_resample,
                                       on_conversion=on_conversion)
                rows = []
                for s, res in zip(chunk, results, strict=True):
                    prov = res.provenance
                    for p in pools:
                        if (s.id, name, p) in done:
                            continue
                        rows.append([s.id, s.reference, name, f"{res.quality(p):.6f}", p,
                                     res.n_patches, f"{res.seconds:.3f}",
                                     prov["backbone"]["label"], prov["backbone"]["sha256"],
                                     prov["weights"]["sha256"]])
                        done.add((s.id, name, p))
                appender.write(rows)
                summary.rows += len(rows)
                summary.scored += len(chunk)
                bar.update(len(chunk))
    finally:
        bar.close()
        appender.close()
    return summary
