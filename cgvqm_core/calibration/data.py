"""What is calibrated on: videos of one or more studies with their human scores.

A dataset is a stimulus manifest plus a DMOS CSV (contract 5 of the design: ``stimulus,
reference, method, level, dmos, ci95_low, ci95_high, mos, n_ratings, model``). Rows join the
manifest's stimuli by ``stimulus`` id; the scene (for scene-disjoint splits) comes from the
manifest.

Direction of the human scores: this toolkit's DMOS is on the quality scale (ITU-T P.910:
DMOS = MOS - MOS(reference) + 100, so 100 = as good as the reference), the same direction as
CGVQM's q = 100 - error. The target is then ``clip(DMOS, 0, 100)``. DMOS files on an
impairment scale (larger = worse, as in the CGVQM authors' data, where the target was
``100 - clip(DMOS, 0, 100)``) are read with ``dmos_scale="impairment"``. The PLCC objective
does not care about the sign, but the scale anchoring does.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pandas as pd

from stimuli_manifests import StimuliError, load_manifest

from ..errors import CGVQMError
from .arguments import DMOS_SCALES, DatasetSpec

log = logging.getLogger(__name__)

DMOS_COLUMNS = ("stimulus", "dmos")


def read_dmos_csv(path: str | Path) -> pd.DataFrame:
    """Read a DMOS CSV (contract 5); only ``stimulus`` and ``dmos`` are required."""
    path = Path(path)
    try:
        df = pd.read_csv(path, dtype={"stimulus": str, "reference": str})
    except FileNotFoundError:
        raise CGVQMError(f"{path}: no such DMOS file") from None
    except (OSError, pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise CGVQMError(f"{path}: not a readable DMOS CSV ({exc})") from None
    missing = [c for c in DMOS_COLUMNS if c not in df.columns]
    if missing:
        raise CGVQMError(f"{path}: DMOS CSV lacks column(s) {', '.join(missing)} (expected the "
                         "columns stimulus, reference, method, level, dmos, ... of `cgvq-analyze "
                         "dmos`)")
    if df["stimulus"].duplicated().any():
        dup = df.loc[df["stimulus"].duplicated(), "stimulus"].tolist()[:5]
        raise CGVQMError(f"{path}: stimulus id(s) listed twice: {', '.join(dup)}")
    numbers = pd.to_numeric(df["dmos"], errors="coerce")
    bad = df.loc[numbers.isna() & df["dmos"].notna(), ["stimulus", "dmos"]]
    if len(bad):
        shown = ", ".join(f"{s}: {d!r}" for s, d in bad.head(3).itertuples(index=False))
        raise CGVQMError(f"{path}: {len(bad)} DMOS value(s) are not numbers ({shown}); "
                         "leave a value empty to leave its video out")
    df["dmos"] = numbers
    return df


def load_dataset(spec: DatasetSpec, *, dmos_scale: str = "quality",
                 include_references: bool = False) -> pd.DataFrame:
    """One row per rated video to calibrate on.

    Columns: dataset, stimulus, reference, scene, method, level, dmos, target, test_path,
    ref_path. Hidden references (a video compared with itself: zero error) are left out
    unless ``include_references``; rows without a DMOS are dropped with a warning.
    """
    if dmos_scale not in DMOS_SCALES:
        raise CGVQMError(f"unknown DMOS scale {dmos_scale!r}; choose {' or '.join(DMOS_SCALES)}")
    try:
        loaded = load_manifest(spec.manifest)
    except StimuliError as exc:
        raise CGVQMError(f"dataset {spec.name}: {exc}") from None
    man = loaded.manifest
    dmos = read_dmos_csv(spec.dmos_csv)
    stimuli = {s.id: s for s in man.stimuli(include_hidden_references=True)}
    unknown = sorted(set(dmos["stimulus"]) - set(stimuli))
    if unknown:
        raise CGVQMError(
            f"dataset {spec.name}: {len(unknown)} stimulus id(s) of {spec.dmos_csv} are not in "
            f"{spec.manifest} (e.g. {', '.join(unknown[:5])}); pair each DMOS file with the "
            "manifest of its study"
        )
    if include_references and not any(stimuli[s].is_hidden_reference
                                      for s in dmos["stimulus"]):
        raise CGVQMError(f"--include-references: dataset {spec.name}'s DMOS CSV "
                         f"({spec.dmos_csv}) rates no hidden references: drop it")
    rows = []
    n_nan = 0
    for rec in dmos.itertuples(index=False):
        stim = stimuli[rec.stimulus]
        if stim.is_hidden_reference and not include_references:
            continue
        if not np.isfinite(rec.dmos):
            n_nan += 1
            continue
        d = float(rec.dmos)
        target = float(np.clip(d, 0.0, 100.0))
        if dmos_scale == "impairment":
            target = 100.0 - target
        try:
            test_path = loaded.stimulus_path(stim.id)
            ref_path = loaded.reference_path(stim.reference)
        except StimuliError as exc:
            raise CGVQMError(f"dataset {spec.name}: {exc}") from None
        rows.append({
            "dataset": spec.name, "stimulus": stim.id, "reference": stim.reference,
            "scene": stim.scene, "method": stim.method, "level": stim.level, "dmos": d,
            "target": target,
            "test_path": str(test_path), "ref_path": str(ref_path),
            "test_sha256": stim.sha256 or "",
            "ref_sha256": man.reference_by_id(stim.reference).sha256 or "",
        })
    if n_nan:
        log.warning("dataset %s: %d row(s) without a DMOS value were left out", spec.name, n_nan)
    if len(rows) < 3:
        raise CGVQMError(f"dataset {spec.name}: {len(rows)} usable rated video(s); calibration "
                         "needs at least 3 (and more than one scene)")
    targets = [r["target"] for r in rows]
    if max(targets) == min(targets):
        raise CGVQMError(f"dataset {spec.name}: every usable DMOS of {spec.dmos_csv} is "
                         f"{targets[0]:g} (clipped to 0..100), so no correlation with it is "
                         "defined; calibrate on scores that vary")
    return pd.DataFrame(rows)


def load_datasets(specs: list[DatasetSpec], **kw: object) -> pd.DataFrame:
    """All datasets' rows, one table (names must be distinct)."""
    names = [s.name for s in specs]
    if len(set(names)) != len(names):
        raise CGVQMError(f"dataset names must be distinct, got {', '.join(names)}")
    if not specs:
        raise CGVQMError("give at least one --dataset NAME=MANIFEST:DMOS_CSV")
    return pd.concat([load_dataset(s, **kw) for s in specs], ignore_index=True)  # type: ignore[arg-type]
