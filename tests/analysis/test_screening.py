"""The default screening (ITU-T P.913 correlation against the leave-one-out panel, iterated,
confirmed by the MLE inconsistency) is not fooled by rater bias or by masking.

Validated on injected raters of known kind (random, inverted, consistent-but-offset, partial),
in generated panels (run everywhere) and in SUREAL's real NFLX panel (with ../shared).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from analysis.inputs import ratings_from_frame
from analysis.quality import loo_correlation
from analysis.screening import screen_raters
from analysis.screening.p913 import R1_MIN, Z_MAX, loo_hrc_correlation, robust_z
from analysis.sureal_io import load_sureal
from analysis.synthetic import synthetic_study

KINDS = {"Xrandom": "random", "Xinverted": "inverted", "Xoffset1": "offset:-20",
         "Xoffset2": "offset:-20", "Xpartial": "partial:0.6"}


def test_leave_one_out_correlation_against_a_direct_computation() -> None:
    rng = np.random.default_rng(0)
    means = rng.normal(50, 10, (30, 6)) + np.arange(30)[:, None]
    means[3, 2] = np.nan
    r = loo_correlation(means)
    for s in range(6):
        others = np.nanmean(np.delete(means, s, axis=1), axis=1)
        ok = np.isfinite(means[:, s])
        assert r[s] == pytest.approx(np.corrcoef(means[ok, s], others[ok])[0, 1])
    # r2: per-HRC means of the rater against the others' per-HRC means
    hrc = np.array(list("abcde") * 6)
    r2 = loo_hrc_correlation(np.nan_to_num(means, nan=50.0), hrc)
    full = np.nan_to_num(means, nan=50.0)
    own = np.array([full[hrc == h, 0].mean() for h in "abcde"])
    oth = np.array([full[hrc == h, 1:].mean() for h in "abcde"])
    assert r2[0] == pytest.approx(np.corrcoef(own, oth)[0, 1])


def test_robust_z_is_iglewicz_hoaglin() -> None:
    v = np.array([1.0, 1.1, 0.9, 1.05, 0.95, 3.0])
    med = np.median(v)
    mad = np.median(np.abs(v - med))
    assert robust_z(v, 0.0)[-1] == pytest.approx(0.6745 * (3.0 - med) / mad)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_injected_raters_of_known_kind_generated_panel(seed: int) -> None:
    st = synthetic_study(n_scenes=6, methods=("blur", "noise"), levels=3, n_raters=14,
                         noise_sd=8, bias_sd=5, seed=seed, special=KINDS)
    rs = ratings_from_frame(st.ratings, st.manifest)
    res = screen_raters(rs)
    assert res.method == "p913"
    assert sorted(res.removed_names) == ["Xinverted", "Xrandom"]
    for r in res.removed:  # every removal names its statistics and thresholds
        assert f"< {R1_MIN}" in r.reason and f"> {Z_MAX}" in r.reason
        assert r.statistic < R1_MIN
    t = res.table
    assert set(t.index) == set(rs.raters)
    assert (t.loc[["Xoffset1", "Xoffset2", "Xpartial"], "decision"] == "kept").all()
    assert t.loc["Xoffset1", "r1"] > 0.85  # an offset does not change a correlation


def test_the_masking_scenario_of_the_issue() -> None:
    """A rater with r about -0.2 with everyone and repeat r below 0, next to two consistent
    raters with a -20 offset: Grubbs on the mean absolute deviation keeps the bad rater (the
    offsets inflate the spread) or removes an offset rater; the default removes exactly the
    bad one."""
    st = synthetic_study(n_scenes=5, methods=("blur", "noise"), levels=2, n_raters=5,
                         noise_sd=6, bias_sd=3, seed=7,
                         special={"Xbad": "random", "Xoff1": "offset:-20",
                                  "Xoff2": "offset:-20"})
    rs = ratings_from_frame(st.ratings, st.manifest)
    res = screen_raters(rs, "p913")
    assert res.removed_names == ["Xbad"]
    grubbs = screen_raters(rs, "grubbs")
    assert grubbs.removed_names != ["Xbad"]  # the paper's rule is fooled here


def test_clean_panels_keep_everyone() -> None:
    for seed in (11, 12, 13):
        st = synthetic_study(n_scenes=6, levels=2, n_raters=12, noise_sd=8, bias_sd=6,
                             seed=seed)
        res = screen_raters(ratings_from_frame(st.ratings, st.manifest))
        assert res.removed == [], (seed, res.removed_names)


def test_a_rater_with_no_variance_is_removed() -> None:
    st = synthetic_study(n_scenes=5, levels=2, n_raters=10, noise_sd=6, seed=4)
    frame = st.ratings.copy()
    frame.loc[frame["participant"] == "P03", "rating"] = 50.0
    res = screen_raters(ratings_from_frame(frame, st.manifest))
    assert res.removed_names == ["P03"]
    assert "no variance" in res.removed[0].reason


# -- real data: SUREAL's NFLX panel ---------------------------------------------------------
def test_nflx_four_known_noisy_raters(sureal_dir) -> None:
    rs = load_sureal(sureal_dir / "NFLX_dataset_public_raw_last4outliers.py")
    res = screen_raters(rs)
    assert sorted(res.removed_names, key=int) == ["26", "27", "28", "29"]
    # and none of the 26 original raters
    clean = screen_raters(load_sureal(sureal_dir / "NFLX_dataset_public_raw.py"))
    assert clean.removed == []
    # rater 6 has r1 below 0.75 but ordinary inconsistency: a near-miss, explained
    assert clean.table.loc["6", "r1"] < R1_MIN
    assert clean.table.loc["6", "reason"].startswith("near-miss, kept")


def test_nflx_with_injected_raters(sureal_dir) -> None:
    rs = load_sureal(sureal_dir / "NFLX_dataset_public_raw.py")
    rng = np.random.default_rng(1)
    n = rs.n_stimuli
    base = rs.scores[:, :, 0]
    mos = np.nanmean(base, axis=1)
    extra = {
        "random": rng.integers(1, 6, n).astype(float),
        "inverted": np.clip(np.round(6 - mos + rng.normal(0, 0.5, n)), 1, 5),
        "offset-a": np.clip(base[:, 3] - 1, 1, 5),  # consistent raters one grade harsher
        "offset-b": np.clip(base[:, 7] - 1, 1, 5),
        "partial": np.where(rng.random(n) < 0.4, base[:, 11], np.nan),
    }
    scores = np.concatenate([rs.scores, np.stack(list(extra.values()), axis=1)[:, :, None]],
                            axis=1)
    mixed = replace(rs, raters=[*rs.raters, *extra], scores=scores)
    res = screen_raters(mixed)
    assert sorted(res.removed_names) == ["inverted", "random"]
    assert (res.table.loc[["offset-a", "offset-b", "partial"], "decision"] == "kept").all()
