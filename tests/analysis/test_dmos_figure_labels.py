"""The DMOS figure's stimulus labels read at the size they are shown: levels upright under
each point and each method named once under its levels, none overlapping another."""

from __future__ import annotations

from itertools import combinations
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg

import analysis.figures as figures_module
from analysis.figures import _level_groups, _two_lines
from analysis.inputs import ratings_from_frame
from analysis.pipeline import AnalysisConfig, run_analysis
from analysis.synthetic import synthetic_study


def _drawn_dmos_figure(tmp_path: Path, monkeypatch, **study):
    st = synthetic_study(n_raters=6, seed=2, **study)
    a = run_analysis(ratings_from_frame(st.ratings, st.manifest),
                     AnalysisConfig(outliers="none", n_boot=10, n_splits=4, ci_draws=2),
                     progress=False)
    drawn = {}
    save = figures_module._save

    def keep(fig, path, **kw):
        drawn["fig"] = fig
        return save(fig, path, **kw)

    monkeypatch.setattr(figures_module, "_save", keep)
    figures_module.dmos_per_scene(a, tmp_path / "dmos.png")
    return drawn["fig"]


def _labels(ax):
    ticks = [t for t in ax.get_xticklabels() if t.get_text()]
    names = [t for t in ax.texts if t.get_text()]
    return ticks, names


@pytest.mark.parametrize("study, names", [
    (dict(n_scenes=2, methods=("noise", "blur"), levels=3), {"blur", "noise"}),
    (dict(n_scenes=2, methods=("gaussian_blur", "jpeg_compression", "taa_ghosting"), levels=4),
     {"gaussian_blur", "jpeg_\ncompression", "taa_ghosting"}),
    (dict(n_scenes=1, methods=("a", "b", "c", "d", "e"), levels=5), set("abcde")),
])
def test_levels_and_methods_are_upright_readable_and_apart(tmp_path, monkeypatch, study, names):
    fig = _drawn_dmos_figure(tmp_path, monkeypatch, **study)
    renderer = FigureCanvasAgg(fig).get_renderer()
    fig.draw(renderer)
    page = fig.bbox
    levels = study["levels"]
    for ax in fig.axes:
        ticks, methods = _labels(ax)
        assert len(ticks) == levels * len(study["methods"])
        assert {t.get_text().removeprefix("L") for t in ticks} == {str(i + 1)
                                                                    for i in range(levels)}
        assert {t.get_text() for t in methods} == names  # each method once
        boxes = []
        for t in ticks + methods:
            assert t.get_rotation() == 0 and t.get_fontsize() >= 8
            box = t.get_window_extent(renderer)
            assert page.x0 <= box.x0 and box.x1 <= page.x1 and page.y0 <= box.y0
            boxes.append(box)
        for b1, b2 in combinations(boxes, 2):
            assert not b1.overlaps(b2), (b1, b2)
        # each method's name sits under the middle of its own levels (methods sort by name)
        for k, method in enumerate(sorted(study["methods"])):
            (name,) = [t for t in methods if t.get_text().replace("\n", "") == method]
            box = name.get_window_extent(renderer)
            first = ticks[k * levels].get_window_extent(renderer)
            last = ticks[(k + 1) * levels - 1].get_window_extent(renderer)
            assert abs((box.x0 + box.x1) / 2 - (first.x0 + last.x1) / 2) < 3
            assert box.y1 < first.y0  # below the level ticks

def test_labels_without_levels_or_too_many_fall_back_to_whole_names():
    sureal_like = pd.DataFrame({"method": ["distorted"] * 3, "level": [np.nan] * 3,
                                "stimulus": ["A_1", "A_2", "A_3"]})
    assert _level_groups(sureal_like) is None
    crowded = pd.DataFrame({"method": ["m"] * 40, "level": range(1, 41),
                            "stimulus": [f"S{i}" for i in range(40)]})
    assert _level_groups(crowded) is None  # 40 stimuli: not even "12" fits in a slot
    ours = pd.DataFrame({"method": ["blur", "blur", "noise"], "level": [1, 2, 1],
                         "stimulus": ["S_b1", "S_b2", "S_n1"]})
    assert _level_groups(ours) == (["L1", "L2", "L1"], [("blur", 0, 1), ("noise", 2, 2)])
    assert _two_lines("jpeg_compression") == "jpeg_\ncompression"
    assert _two_lines("motion blur strong") in {"motion\nblur strong", "motion blur\nstrong"}
    assert _two_lines("ghosting") == "ghosting"
