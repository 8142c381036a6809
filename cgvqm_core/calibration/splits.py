"""Scene-disjoint train/validation/test splits, reproducible from a seed.

A metric calibrated on some frames of a scene and tested on other distortions of the same
scene looks better than it is, so every split assigns whole scenes: within each dataset, a
share of its scenes goes to training (as the paper's 20:80 train:test), the rest to test,
and optionally a share of the training scenes is held out for validation (to pick the step
whose weights are kept without looking at the test scenes).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import CGVQMError


@dataclass(frozen=True)
class Split:
    """Which videos train, validate and test; one seed, one train ratio."""

    seed: int
    train_ratio: float
    train: np.ndarray  # (V,) bool
    val: np.ndarray  # (V,) bool (all False when no validation is held out)
    test: np.ndarray  # (V,) bool
    train_scenes: tuple[str, ...]
    val_scenes: tuple[str, ...]
    test_scenes: tuple[str, ...]


def _share(n: int, ratio: float, *, keep_rest: bool) -> int:
    """round(n * ratio) clipped to [1, n - 1] (or [1, n] when nothing must remain)."""
    k = round(n * ratio)
    return max(1, min(k, n - 1 if keep_rest else n))


def training_scenes(scene_counts: dict[str, int], ratios: Sequence[float]) -> list[str]:
    """What each train ratio gives in whole scenes, per dataset: a line for each ratio that
    rounding moves (0.2 of 3 scenes trains on 1, a third); two ratios that give the same
    split are refused, since the validation table would show one split under two labels."""
    notes: list[str] = []
    seen: dict[tuple[int, ...], float] = {}
    for d, n in scene_counts.items():
        if n < 2 and any(r < 1.0 for r in ratios):
            raise CGVQMError(f"dataset {d!r} has one scene: a scene-disjoint split needs two")
    for ratio in ratios:
        ks = tuple(_share(n, ratio, keep_rest=ratio < 1.0) for n in scene_counts.values())
        if ks in seen:
            raise CGVQMError(
                f"--train-ratio {seen[ks]:g} and {ratio:g} give the same split in whole "
                f"scenes (" + ", ".join(f"{k} of {n} in {d}" for k, (d, n) in
                                         zip(ks, scene_counts.items(), strict=True))
                + "): drop one")
        seen[ks] = ratio
        for k, (d, n) in zip(ks, scene_counts.items(), strict=True):
            if f"{k / n:.2f}" != f"{ratio:.2f}":  # as the validation table shows it
                notes.append(f"train ratio {ratio:g} trains on {k} of {n} scenes in {d} "
                             f"({k / n:.2f})")
    return notes


def scene_split(scenes: Sequence[str], datasets: Sequence[str], train_ratio: float, seed: int,
                *, val_ratio: float = 0.0) -> Split:
    """Split videos by scene, per dataset: ``train_ratio`` of each dataset's scenes train
    (at least one, and at least one scene left for test), the rest test; ``val_ratio`` of
    the training scenes (at least one when > 0) validate instead of training.

    Scene names are qualified by dataset, so two datasets may reuse a scene name without
    being tied together. ``train_ratio = 1`` puts every scene in training (no test).
    """
    if not 0.0 < train_ratio <= 1.0:
        raise CGVQMError(f"train ratio must be in (0, 1], got {train_ratio}")
    if not 0.0 <= val_ratio < 1.0:
        raise CGVQMError(f"validation ratio must be in [0, 1), got {val_ratio}")
    scenes = np.asarray([f"{d}\x1f{s}" for d, s in zip(datasets, scenes, strict=True)])
    dsets = np.asarray(list(datasets))
    rng = np.random.default_rng(seed)
    train_s: list[str] = []
    val_s: list[str] = []
    test_s: list[str] = []
    for d in sorted(set(dsets.tolist())):
        names = np.array(sorted(set(scenes[dsets == d].tolist())))
        if train_ratio < 1.0 and len(names) < 2:
            raise CGVQMError(f"dataset {d!r} has one scene: a scene-disjoint split needs two")
        names = names[rng.permutation(len(names))]
        k = _share(len(names), train_ratio, keep_rest=train_ratio < 1.0)
        tr, te = names[:k].tolist(), names[k:].tolist()
        if val_ratio > 0:
            if len(tr) < 2:
                raise CGVQMError(
                    f"dataset {d!r}: {len(tr)} training scene(s) cannot be split further into "
                    "training and validation; use more scenes, a larger train ratio, or "
                    "select weights by training loss or a fixed step count"
                )
            kv = _share(len(tr), val_ratio, keep_rest=True)
            val_s += tr[:kv]
            tr = tr[kv:]
        train_s += tr
        test_s += te
    return Split(
        seed=seed,
        train_ratio=train_ratio,
        train=np.isin(scenes, train_s),
        val=np.isin(scenes, val_s),
        test=np.isin(scenes, test_s),
        train_scenes=tuple(_plain(train_s)),
        val_scenes=tuple(_plain(val_s)),
        test_scenes=tuple(_plain(test_s)),
    )


def _plain(qualified: list[str]) -> list[str]:
    return [q.replace("\x1f", ":") for q in qualified]


def repeated_splits(scenes: Sequence[str], datasets: Sequence[str], train_ratio: float,
                    seeds: Sequence[int], *, val_ratio: float = 0.0) -> list[Split]:
    """One :func:`scene_split` per seed."""
    return [scene_split(scenes, datasets, train_ratio, s, val_ratio=val_ratio) for s in seeds]
