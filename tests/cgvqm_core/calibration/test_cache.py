"""The feature cache: computed once, resumable after an interruption, keyed by content."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from cgvqm_core.calibration import FeatureCache, pack
from cgvqm_core.errors import CGVQMError

N = 131


def _videos(tmp_path, n_refs=3, per_ref=4):
    rows = []
    for r in range(n_refs):
        ref = tmp_path / f"ref{r}.bin"
        ref.write_bytes(f"reference {r}".encode())
        for k in range(per_ref):
            t = tmp_path / f"ref{r}_t{k}.bin"
            t.write_bytes(f"test {r} {k}".encode())
            rows.append({"dataset": "d", "stimulus": f"R{r}T{k}", "test_path": str(t),
                         "ref_path": str(ref)})
    return pd.DataFrame(rows)


class Counting:
    """A fake feature function: m derived from the file names; counts and can fail."""

    def __init__(self, fail_after: int | None = None):
        self.calls: list[str] = []
        self.fail_after = fail_after

    def __call__(self, ref, tests):
        out = []
        for t in tests:
            if self.fail_after is not None and len(self.calls) >= self.fail_after:
                raise KeyboardInterrupt
            self.calls.append(t)
            seed = sum(t.encode())
            out.append(np.random.default_rng(seed).random((2 + seed % 5, N)).astype(np.float32))
        return out


SETTINGS = {"variant": "cgvqm-2", "n_channels": N, "backbone_sha256": "ab" * 32,
            "patch_scale": 4}


def test_interrupted_build_resumes_with_only_the_missing_videos(tmp_path):
    items = _videos(tmp_path)
    root = tmp_path / "cache"
    first = Counting(fail_after=5)
    with pytest.raises(KeyboardInterrupt):
        FeatureCache(root, SETTINGS).build(items, first, group_size=2, show_progress=False)
    # groups of two: the 4 videos of the two completed groups are saved, the 5th was lost
    second = Counting()
    got = FeatureCache(root, SETTINGS).build(items, second, group_size=2, show_progress=False)
    assert len(second.calls) == len(items) - 4
    assert not set(second.calls) & set(first.calls[:4])
    reference = Counting()
    expected = [reference(r, [t])[0] for t, r in zip(items.test_path, items.ref_path,
                                                      strict=True)]
    for a, b in zip(got, expected, strict=True):
        np.testing.assert_array_equal(a, b)
    third = Counting()
    FeatureCache(root, SETTINGS).build(items, third, show_progress=False)
    assert third.calls == []
    index = json.loads((FeatureCache(root, SETTINGS).folder / "index.json").read_text())
    assert len(index["entries"]) == len(items)
    assert not list(FeatureCache(root, SETTINGS).folder.glob("*.tmp"))


def test_videos_sharing_a_reference_are_computed_together(tmp_path):
    items = _videos(tmp_path, n_refs=2, per_ref=3)
    refs_seen = []

    def fn(ref, tests):
        refs_seen.append((ref, len(tests)))
        return Counting()(ref, tests)

    FeatureCache(tmp_path / "c", SETTINGS).build(items, fn, group_size=8, show_progress=False)
    assert sorted(n for _, n in refs_seen) == [3, 3]


def test_key_is_the_content_and_settings_separate_caches(tmp_path):
    items = _videos(tmp_path, n_refs=1, per_ref=2)
    root = tmp_path / "cache"
    FeatureCache(root, SETTINGS).build(items, Counting(), show_progress=False)
    moved = tmp_path / "moved"
    moved.mkdir()
    renamed = items.copy()
    for col in ("test_path", "ref_path"):
        for i, p in enumerate(items[col]):
            new = moved / f"{col}{i}.bin"
            new.write_bytes(Path(p).read_bytes())
            renamed.loc[i, col] = str(new)
    again = Counting()
    FeatureCache(root, SETTINGS).build(renamed, again, show_progress=False)
    assert again.calls == []  # same bytes, same entries
    other = Counting()
    FeatureCache(root, {**SETTINGS, "backbone_sha256": "cd" * 32}).build(
        items, other, show_progress=False)
    assert len(other.calls) == 2


def test_a_corrupt_entry_is_recomputed(tmp_path):
    items = _videos(tmp_path, n_refs=1, per_ref=2)
    cache = FeatureCache(tmp_path / "c", SETTINGS)
    cache.build(items, Counting(), show_progress=False)
    victim = sorted(cache.folder.glob("*.npy"))[0]
    victim.write_bytes(b"not an array")
    again = Counting()
    cache.build(items, again, show_progress=False)
    assert len(again.calls) == 1


def test_wrong_shapes_are_refused(tmp_path):
    items = _videos(tmp_path, n_refs=1, per_ref=1)
    with pytest.raises(CGVQMError, match="shape"):
        FeatureCache(tmp_path / "c", SETTINGS).build(
            items, lambda r, ts: [np.zeros((3, 7), np.float32) for _ in ts], show_progress=False)


def test_pack_pads_with_zeros():
    a, b = np.ones((2, 3), np.float32), 2 * np.ones((4, 3), np.float32)
    M, counts = pack([a, b])
    assert M.shape == (2, 4, 3) and counts.tolist() == [2, 4]
    assert (M[0, 2:] == 0).all() and (M[1] == 2).all()


def test_cgvqm2_features_are_sliced_from_a_cgvqm5_cache(tmp_path):
    items = _videos(tmp_path, n_refs=1, per_ref=3)
    root = tmp_path / "cache"
    five = {**SETTINGS, "variant": "cgvqm-5", "n_channels": 1027}

    def wide(ref, tests):
        return [np.random.default_rng(sum(t.encode())).random((3, 1027)).astype(np.float32)
                for t in tests]

    full = FeatureCache(root, five).build(items, wide, show_progress=False)
    calls = Counting()
    two = FeatureCache(root, SETTINGS, supersets=[FeatureCache(root, five)])
    got = two.build(items, calls, show_progress=False)
    assert calls.calls == []
    for a, b in zip(got, full, strict=True):
        np.testing.assert_array_equal(a, b[:, :N])
