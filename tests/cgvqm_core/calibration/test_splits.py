"""Scene-disjoint splits: no scene on two sides, for any seed and ratio."""

from __future__ import annotations

import numpy as np
import pytest

from cgvqm_core.calibration import repeated_splits, scene_split
from cgvqm_core.errors import CGVQMError


def _layout(seed: int):
    """Two datasets that reuse scene names, uneven videos per scene."""
    rng = np.random.default_rng(seed)
    scenes, dsets = [], []
    for d, n_scenes in (("A", 10), ("B", 7)):
        for s in range(n_scenes):
            k = int(rng.integers(1, 9))
            scenes += [f"scene{s}"] * k
            dsets += [d] * k
    return scenes, dsets


@pytest.mark.parametrize("ratio", [0.2, 0.5, 0.8])
@pytest.mark.parametrize("val_ratio", [0.0, 0.25])
def test_no_scene_is_on_two_sides_over_many_seeds(ratio, val_ratio):
    scenes, dsets = _layout(0)
    keys = np.array([f"{d}/{s}" for d, s in zip(dsets, scenes, strict=True)])
    if val_ratio > 0 and round(7 * ratio) < 2:  # B: 1 training scene cannot also validate
        with pytest.raises(CGVQMError, match="validation"):
            scene_split(scenes, dsets, ratio, 0, val_ratio=val_ratio)
        return
    for seed in range(100):
        sp = scene_split(scenes, dsets, ratio, seed, val_ratio=val_ratio)
        parts = [set(keys[sp.train]), set(keys[sp.val]), set(keys[sp.test])]
        assert not parts[0] & parts[1] and not parts[0] & parts[2] and not parts[1] & parts[2]
        assert (sp.train.astype(int) + sp.val + sp.test == 1).all()  # every video, once
        for d, n_scenes in (("A", 10), ("B", 7)):
            in_d = np.array(dsets) == d
            n_train = len(set(keys[sp.train & in_d]))
            n_val = len(set(keys[sp.val & in_d]))
            n_test = len(set(keys[sp.test & in_d]))
            assert n_train >= 1 and n_test >= 1
            assert n_train + n_val + n_test == n_scenes
            expected = max(1, min(round(n_scenes * ratio), n_scenes - 1))
            assert n_train + n_val == expected
            assert (n_val >= 1) == (val_ratio > 0)


def test_splits_are_reproducible_and_vary_with_the_seed():
    scenes, dsets = _layout(1)
    a = repeated_splits(scenes, dsets, 0.5, range(10))
    b = repeated_splits(scenes, dsets, 0.5, range(10))
    assert all((x.train == y.train).all() for x, y in zip(a, b, strict=True))
    assert len({tuple(s.train_scenes) for s in a}) > 5


def test_a_shared_scene_name_does_not_tie_two_datasets():
    scenes = ["s1", "s1", "s2", "s2"] * 2
    dsets = ["A"] * 4 + ["B"] * 4
    seen = set()
    for seed in range(40):
        sp = scene_split(scenes, dsets, 0.5, seed)
        seen.add((tuple(sp.train[:4]), tuple(sp.train[4:])))
    assert len(seen) == 4  # A and B choose their training scene independently


def test_one_scene_cannot_be_split():
    with pytest.raises(CGVQMError, match="one scene"):
        scene_split(["s"] * 5, ["A"] * 5, 0.5, 0)
    with pytest.raises(CGVQMError, match="validation"):
        scene_split(["a", "b", "c"], ["A"] * 3, 0.2, 0, val_ratio=0.25)


def test_training_scenes_says_what_rounding_does_and_refuses_one_split_twice():
    """0.1 and 0.9 of two scenes both train on one: the table would show one split under
    two labels. A ratio that rounding moves is said in whole scenes."""
    from cgvqm_core.calibration.splits import training_scenes

    with pytest.raises(CGVQMError, match=r"0\.1 and 0\.9 give the same split .*1 of 2 in a"):
        training_scenes({"a": 2}, [0.1, 0.9])
    # scene_split agrees on the counts the notes give
    assert training_scenes({"a": 5, "b": 4}, [0.2]) == [
        "train ratio 0.2 trains on 1 of 4 scenes in b (0.25)"]
    split = scene_split(["s1", "s2", "s3", "s4"], ["b"] * 4, 0.2, seed=0)
    assert len(split.train_scenes) == 1
    assert training_scenes({"a": 5}, [0.2, 0.4, 0.6]) == []  # 1, 2 and 3 of 5: exact
    with pytest.raises(CGVQMError, match="has one scene"):
        training_scenes({"a": 1}, [0.5])
