"""Scene-disjoint train/validation/test splits, reproducible from a seed.

A metric calibrated on some frames of a scene and tested on other distortions of the same
scene looks better than it is, so every split assigns whole scenes: within each dataset, a
share of its scenes goes to training (as the paper's 20:80 train:test), the rest to test,
and optionally a share of the training scenes is held out for validation (to pick the step
whose weights are kept without looking at the test scenes).

The splits of one train ratio are distinct (:func:`distinct_splits`): with few scenes, seeds
repeat splits (5 scenes at 20:80 have only 5), and counting a copy as another repetition
narrows the interval over splits without new evidence. When there are no more possible
splits than repeats asked for, all of them are used; otherwise seeds draw until that many
distinct ones are found (sampling without replacement).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..errors import CGVQMError


@dataclass(frozen=True)
class Split:
    """Which videos train, validate and test; one train ratio, drawn by one seed (None
    when all possible splits were enumerated instead)."""

    seed: int | None
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


def _names_by_dataset(scenes: Sequence[str], datasets: Sequence[str], train_ratio: float
                      ) -> tuple[np.ndarray, dict[str, list[str]]]:
    """Videos' dataset-qualified scene names, and each dataset's sorted scene names."""
    if not 0.0 < train_ratio <= 1.0:
        raise CGVQMError(f"train ratio must be in (0, 1], got {train_ratio}")
    qualified = np.asarray([f"{d}\x1f{s}" for d, s in zip(datasets, scenes, strict=True)])
    dsets = np.asarray(list(datasets))
    by_dataset: dict[str, list[str]] = {}
    for d in sorted(set(dsets.tolist())):
        names = sorted(set(qualified[dsets == d].tolist()))
        if train_ratio < 1.0 and len(names) < 2:
            raise CGVQMError(f"dataset {d!r} has one scene: a scene-disjoint split needs two")
        by_dataset[d] = names
    return qualified, by_dataset


def _val_share(d: str, n_train: int, val_ratio: float) -> int:
    """How many of a dataset's training scenes validate (0 without validation)."""
    if val_ratio <= 0:
        return 0
    if n_train < 2:
        raise CGVQMError(
            f"dataset {d!r}: {n_train} training scene(s) cannot be split further into "
            "training and validation; use more scenes, a larger train ratio, or "
            "select weights by training loss or a fixed step count"
        )
    return _share(n_train, val_ratio, keep_rest=True)


def _make_split(qualified: np.ndarray, seed: int | None, train_ratio: float,
                parts: Sequence[tuple[list[str], list[str], list[str]]]) -> Split:
    """A split from each dataset's (train, val, test) scene names."""
    train_s = [x for tr, _, _ in parts for x in tr]
    val_s = [x for _, va, _ in parts for x in va]
    test_s = [x for _, _, te in parts for x in te]
    return Split(
        seed=seed,
        train_ratio=train_ratio,
        train=np.isin(qualified, train_s),
        val=np.isin(qualified, val_s),
        test=np.isin(qualified, test_s),
        train_scenes=tuple(_plain(train_s)),
        val_scenes=tuple(_plain(val_s)),
        test_scenes=tuple(_plain(test_s)),
    )


def scene_split(scenes: Sequence[str], datasets: Sequence[str], train_ratio: float, seed: int,
                *, val_ratio: float = 0.0) -> Split:
    """Split videos by scene, per dataset: ``train_ratio`` of each dataset's scenes train
    (at least one, and at least one scene left for test), the rest test; ``val_ratio`` of
    the training scenes (at least one when > 0) validate instead of training.

    Scene names are qualified by dataset, so two datasets may reuse a scene name without
    being tied together. ``train_ratio = 1`` puts every scene in training (no test).
    """
    if not 0.0 <= val_ratio < 1.0:
        raise CGVQMError(f"validation ratio must be in [0, 1), got {val_ratio}")
    qualified, by_dataset = _names_by_dataset(scenes, datasets, train_ratio)
    rng = np.random.default_rng(seed)
    parts = []
    for d, sorted_names in by_dataset.items():
        names = np.array(sorted_names)[rng.permutation(len(sorted_names))]
        k = _share(len(names), train_ratio, keep_rest=train_ratio < 1.0)
        tr, te = names[:k].tolist(), names[k:].tolist()
        kv = _val_share(d, len(tr), val_ratio)
        parts.append((tr[kv:], tr[:kv], te))
    return _make_split(qualified, seed, train_ratio, parts)


def _plain(qualified: list[str]) -> list[str]:
    return [q.replace("\x1f", ":") for q in qualified]


def repeated_splits(scenes: Sequence[str], datasets: Sequence[str], train_ratio: float,
                    seeds: Sequence[int], *, val_ratio: float = 0.0) -> list[Split]:
    """One :func:`scene_split` per seed (copies included: see :func:`distinct_splits`)."""
    return [scene_split(scenes, datasets, train_ratio, s, val_ratio=val_ratio) for s in seeds]


@dataclass
class SplitSet:
    """The distinct splits of one train ratio, and how they were chosen."""

    train_ratio: float
    splits: list[Split]
    n_possible: int  # distinct scene splits there are at this ratio
    enumerated: bool  # all of them used (no more possible than repeats asked for)
    skipped_seeds: list[int] = field(default_factory=list)  # seeds that repeated a split

    def note(self, repeats: int) -> str | None:
        """A line for the output when the splits are not simply ``repeats`` seeds."""
        r = f"train ratio {self.train_ratio:g}"
        if self.enumerated:
            return (f"{r}: all {self.n_possible} possible scene split(s) used, each once "
                    f"(--repeats {repeats} asked for more than there are)")
        if self.skipped_seeds:
            return (f"{r}: {len(self.splits)} distinct scene splits; seed(s) "
                    f"{', '.join(map(str, self.skipped_seeds[:10]))}"
                    f"{', ...' if len(self.skipped_seeds) > 10 else ''} drew a split already "
                    f"drawn and were skipped ({self.n_possible} possible)")
        return None

    def describe(self) -> dict[str, object]:
        """What the weights file's provenance records of these splits."""
        return {"train_ratio": self.train_ratio, "n_splits": len(self.splits),
                "n_possible": self.n_possible, "enumerated": self.enumerated,
                "seeds": None if self.enumerated else [s.seed for s in self.splits],
                "skipped_seeds": self.skipped_seeds}


def count_splits(scenes: Sequence[str], datasets: Sequence[str], train_ratio: float, *,
                 val_ratio: float = 0.0) -> int:
    """How many distinct scene splits there are: per dataset, the ways to choose its
    training scenes (and among them its validation scenes), multiplied over datasets."""
    _, by_dataset = _names_by_dataset(scenes, datasets, train_ratio)
    total = 1
    for d, names in by_dataset.items():
        k = _share(len(names), train_ratio, keep_rest=train_ratio < 1.0)
        total *= math.comb(len(names), k) * math.comb(k, _val_share(d, k, val_ratio))
    return total


def all_splits(scenes: Sequence[str], datasets: Sequence[str], train_ratio: float, *,
               val_ratio: float = 0.0) -> Iterator[Split]:
    """Every distinct scene split, in a fixed order (for the few-scene case)."""
    qualified, by_dataset = _names_by_dataset(scenes, datasets, train_ratio)
    choices = []
    for d, names in by_dataset.items():
        k = _share(len(names), train_ratio, keep_rest=train_ratio < 1.0)
        kv = _val_share(d, k, val_ratio)
        options = []
        for tr in itertools.combinations(names, k):
            te = [x for x in names if x not in tr]
            for va in itertools.combinations(tr, kv):
                options.append(([x for x in tr if x not in va], list(va), te))
        choices.append(options)
    for parts in itertools.product(*choices):
        yield _make_split(qualified, None, train_ratio, parts)


def _identity(split: Split) -> tuple[tuple[str, ...], tuple[str, ...]]:
    return tuple(sorted(split.train_scenes)), tuple(sorted(split.val_scenes))


def _draw_seeds(seeds: Sequence[int]) -> Iterator[int]:
    """The given seeds, then the next ones after the largest."""
    yield from seeds
    yield from itertools.count(max(seeds) + 1)


def distinct_splits(scenes: Sequence[str], datasets: Sequence[str], train_ratio: float,
                    seeds: Sequence[int], *, val_ratio: float = 0.0) -> SplitSet:
    """``len(seeds)`` distinct scene splits at ``train_ratio`` (see the module doc): all of
    them when there are no more; else the splits of the seeds, a seed that repeats an earlier
    split skipped and a next seed drawn instead (sampling without replacement)."""
    if not seeds:
        raise CGVQMError("at least one split is needed (--repeats 1 or more)")
    repeats = len(seeds)
    possible = count_splits(scenes, datasets, train_ratio, val_ratio=val_ratio)
    if possible <= repeats:
        splits = list(all_splits(scenes, datasets, train_ratio, val_ratio=val_ratio))
        return SplitSet(train_ratio, splits, possible, True)
    seen: set[tuple[tuple[str, ...], tuple[str, ...]]] = set()
    kept: list[Split] = []
    skipped: list[int] = []
    for n, seed in enumerate(_draw_seeds(seeds)):
        if n >= 1000 * repeats:  # astronomically unlikely with more splits than repeats
            raise CGVQMError(f"train ratio {train_ratio:g}: could not draw {repeats} distinct "
                             f"scene splits of {possible}; ask for fewer --repeats")
        split = scene_split(scenes, datasets, train_ratio, seed, val_ratio=val_ratio)
        if _identity(split) in seen:
            skipped.append(seed)
            continue
        seen.add(_identity(split))
        kept.append(split)
        if len(kept) == repeats:
            break
    return SplitSet(train_ratio, kept, possible, False, skipped)
