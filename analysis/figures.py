"""The report's figures, drawn with matplotlib's object API (no pyplot state, no display)."""

from __future__ import annotations

import contextlib
import math
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from matplotlib import colormaps, rc_context
from matplotlib.figure import Figure
from matplotlib.ticker import LogFormatter, MaxNLocator, NullFormatter

from .data import RatingSet
from .intervals import MIN_RATERS_FOR_INTERVAL
from .panel_figure import draw_survey
from .pipeline import Analysis
from .quality import THRESHOLDS

_DPI = 100


def _save(fig: Figure, path: Path, *, tight: bool = True) -> Path:
    """The figure as PNG (for the HTML page) and as PDF beside it (vector, for papers)."""
    if tight:
        fig.tight_layout()
    fig.savefig(path, dpi=_DPI)
    fig.savefig(path.with_suffix(".pdf"))
    return path


def _lowest(t: pd.DataFrame) -> float:
    """The lowest PLCC or SRCC or lower CI bound (at most 0): an axis from there shows every
    whisker whole, including intervals that reach below 0."""
    cols = [c for c in ("plcc", "srcc", "plcc_ci95_low", "srcc_ci95_low") if c in t.columns]
    values = t[cols].to_numpy(dtype=float)
    return min(0.0, float(np.nanmin(values))) if np.isfinite(values).any() else 0.0


def _grid(n: int, max_cols: int = 4) -> tuple[int, int]:
    cols = min(max_cols, max(1, n))
    return math.ceil(n / cols), cols


def _method_colors(methods: list[str]) -> dict[str, tuple]:
    cmap = colormaps["tab10"]
    return {m: cmap(i % 10) for i, m in enumerate(methods)}


def _stimulus_ticks(sd: pd.DataFrame) -> list[str]:
    """Short tick labels (method and level), or the stimulus ids where those would not tell
    the stimuli apart (a SUREAL dataset's are all 'distorted', without a level)."""
    short = [f"{m}{'' if pd.isna(lv) else f' L{int(lv)}'}"
             for m, lv in zip(sd["method"], sd["level"], strict=True)]
    return short if len(set(short)) == len(short) else [str(s) for s in sd["stimulus"]]


_GROUP_FONT = 8
"""Points of the level ticks and method names under a scene's DMOS panel."""
_PANEL_WIDTH_PT = 3.3 * 72
"""About how wide one scene's axes are (4.2 in less its margins), for the fit estimate."""


def _two_lines(name: str) -> str:
    """A method name broken at the separator ("_", "-" or a space) nearest its middle."""
    cuts = [i for i, c in enumerate(name) if c in "_- "]
    if not cuts:
        return name
    cut = min(cuts, key=lambda i: abs(2 * i - len(name)))
    return f"{name[:cut + (name[cut] != ' ')]}\n{name[cut + 1:]}"


def _level_groups(sd: pd.DataFrame) -> tuple[list[str], list[tuple[str, int, int]]] | None:
    """Horizontal level ticks ("L1", or "1" where that is too wide) with each method named
    once under its group of levels (on two lines where one is too wide), or None where they
    would not read: a stimulus without a level, a method and level that repeat, or labels
    estimated wider than their share of the panel (then each stimulus's whole label is drawn
    turned on end, as ``_stimulus_ticks``)."""
    if sd.empty or sd["level"].isna().any():
        return None
    methods = [str(m) for m in sd["method"]]
    levels = [int(lv) for lv in sd["level"]]
    if len(set(zip(methods, levels, strict=True))) != len(sd):
        return None
    slot = _PANEL_WIDTH_PT / len(sd)
    char = 0.6 * _GROUP_FONT  # a generous average glyph width

    def width(text: str) -> float:
        return max(len(line) for line in text.split("\n")) * char

    for ticks in ([f"L{lv}" for lv in levels], [str(lv) for lv in levels]):
        if max(width(t) for t in ticks) <= 0.9 * slot:
            break
    else:
        return None
    groups: list[tuple[str, int, int]] = []  # a method (as drawn), its first and last position
    start = 0
    for i in range(1, len(methods) + 1):
        if i == len(methods) or methods[i] != methods[start]:
            room = 0.95 * slot * (i - start)
            name = methods[start] if width(methods[start]) <= room else _two_lines(methods[start])
            if width(name) > room:
                return None
            groups.append((name, start, i - 1))
            start = i
    return ticks, groups


def _label_stimuli(ax: Any, sd: pd.DataFrame) -> None:
    """A scene panel's x labels: levels with their method under them where they fit,
    otherwise each stimulus's whole label turned on end (small)."""
    x = np.arange(len(sd))
    ax.set_xticks(x)
    ax.set_xlim(-0.6, len(sd) - 0.4)  # every point off the frame, however few there are
    grouped = _level_groups(sd)
    if grouped is None:
        ax.set_xticklabels(_stimulus_ticks(sd), rotation=90, fontsize=6)
        return
    ticks, groups = grouped
    ax.set_xticklabels(ticks, fontsize=_GROUP_FONT)
    for method, first, last in groups:
        ax.annotate(method, xy=((first + last) / 2, 0), xycoords=ax.get_xaxis_transform(),
                    xytext=(0, -2.6 * _GROUP_FONT), textcoords="offset points", ha="center",
                    va="top", fontsize=_GROUP_FONT, color="0.25")
        if first:  # a faint line between two methods' groups
            ax.axvline(first - 0.5, color="0.88", lw=0.8, zorder=0)


def _prediction_offset(j: int, n: int) -> float:
    """Where the j-th of n metrics' predictions sit beside a stimulus's DMOS (at 0): side by
    side to its right in the legend's order, within the stimulus's slot, so that glyphs of
    like predictions do not pile up on one spot."""
    return 0.2 if n == 1 else 0.12 + 0.3 * j / (n - 1)


def dmos_per_scene(a: Analysis, path: Path) -> Path:
    """DMOS with 95% CI per scene, grouped by method and level; metric predictions on top."""
    d = a.dmos()
    d = d[~d["is_hidden_reference"]]
    scenes = list(dict.fromkeys(d["scene"]))
    methods = list(dict.fromkeys(d["method"]))
    colors = _method_colors(methods)
    shapes = {m: "osD^v<>ph"[i % 9] for i, m in enumerate(methods)}  # not by colour alone
    rows, cols = _grid(len(scenes))
    fig = Figure(figsize=(4.2 * cols, 3.4 * rows + 0.4))
    preds = a.metrics.data if a.metrics is not None else {}
    markers = "x+^vsD<>"  # hollow black, beside the filled colour of the DMOS
    # one DMOS axis for every scene, from the lowest CI bound to the top of the scale
    low = float(np.nanmin([d["ci95_low"].min(), d["dmos"].min()]))
    high = float(np.nanmax([d["ci95_high"].max(), d["dmos"].max(), a.screened.ref_score]))
    pad = 0.03 * (high - low or 1.0)
    for k, scene in enumerate(scenes):
        ax = fig.add_subplot(rows, cols, k + 1)
        sd = d[d["scene"] == scene].sort_values(["method", "level"], na_position="last")
        x = np.arange(len(sd))
        for method in dict.fromkeys(sd["method"]):
            sel = (sd["method"] == method).to_numpy()
            r = sd[sel]
            ax.errorbar(x[sel], r["dmos"], yerr=[r["dmos"] - r["ci95_low"],
                                                 r["ci95_high"] - r["dmos"]],
                        fmt=shapes[method], color=colors[method], capsize=2, ms=4, ls="none")
        for j, (name, pdata) in enumerate(preds.items()):
            p = pdata.set_index("stimulus")["predicted"]
            y = [p.get(s, np.nan) for s in sd["stimulus"]]
            ax.plot(x + _prediction_offset(j, len(preds)), y, markers[j % len(markers)],
                    color="k", mfc="none", ms=4.5, mew=0.9, alpha=0.7,
                    label=a.metrics.title(name) if k == 0 and a.metrics else None)
        _label_stimuli(ax, sd)
        ax.set_title(str(scene), fontsize=9)
        ax.set_ylabel("DMOS")
        ax.set_ylim(low - pad, high + pad)
        ax.axhline(a.screened.ref_score, color="0.7", lw=0.8)
        if sd["dmos"].isna().all():  # its hidden reference was never rated
            ax.text(0.5, 0.5, "no DMOS: its hidden reference\nwas not rated", ha="center",
                    va="center", fontsize=8, color="0.3", transform=ax.transAxes)
    handles = [fig.axes[0].plot([], [], shapes[m], color=c)[0] for m, c in colors.items()]
    labels = list(colors)
    if preds:
        h, lab = fig.axes[0].get_legend_handles_labels()
        handles, labels = handles + h, labels + lab
    if (d["dmos"].notna() & d["ci95_low"].isna()).any():  # a point without a bar is no certainty
        handles.append(fig.axes[0].plot([], [], ls="none")[0])
        labels.append(f"no bar: fewer than {MIN_RATERS_FOR_INTERVAL} raters")
    # above the panels: below them it would cover the stimulus labels
    fig.legend(handles, labels, loc="upper center", ncol=min(6, len(labels)), fontsize=8,
               bbox_to_anchor=(0.5, 1.0), frameon=False)
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.4 / (3.4 * rows + 0.4)))
    return _save(fig, path, tight=False)


def metric_scatter(a: Analysis, path: Path) -> Path | None:
    """Each metric against DMOS with its fitted mapping."""
    if a.metrics is None:
        return None
    names = list(a.metrics.data)
    rows, cols = _grid(len(names), 3)
    fig = Figure(figsize=(4.2 * cols, 3.6 * rows))
    table = a.metrics.table.set_index("metric")
    for k, name in enumerate(names):
        ax = fig.add_subplot(rows, cols, k + 1)
        dat = a.metrics.data[name]
        methods = list(dict.fromkeys(dat["method"]))
        colors = _method_colors(methods)
        for m in methods:
            s = dat[dat["method"] == m]
            ax.scatter(s["score"], s["dmos"], s=12, color=colors[m], label=m)
        sign = 1.0 if np.allclose(dat["score"], dat["oriented"]) else -1.0
        grid = np.linspace(dat["score"].min(), dat["score"].max(), 200)
        ax.plot(grid, a.metrics.mappings[name](sign * grid), "k-", lw=1)
        r = table.loc[name]
        flag = " [FLAGGED]" if name in a.metrics.untrained else ""
        title = a.metrics.title(name)
        ax.set_title(f"{title}{flag}\nPLCC {r['plcc']:.3f}  SRCC {r['srcc']:.3f} "
                     f"({a.metrics.mappings[name].kind})", fontsize=8,
                     color="#a00" if flag else "k")
        ax.set_xlabel(f"{title} score" + (" (lower is better)" if sign < 0 else ""))
        ax.ticklabel_format(axis="x", useOffset=False)  # scores near 100 read as they are
        ax.set_ylabel("DMOS")
        if k == 0:
            ax.legend(fontsize=6)
    return _save(fig, path)


def inter_rater_heatmap(a: Analysis, path: Path) -> Path | None:
    if a.reliability is None:
        return None
    m = a.reliability.inter_rater
    n = len(m)
    fig = Figure(figsize=(max(4, 0.3 * n + 2), max(3.5, 0.3 * n + 1.5)))
    ax = fig.add_subplot()
    im = ax.imshow(m.to_numpy(), vmin=min(0, np.nanmin(m.to_numpy())), vmax=1, cmap="viridis")
    ax.set_xticks(range(n), m.columns, rotation=90, fontsize=6)
    ax.set_yticks(range(n), m.index, fontsize=6)
    ax.set_title("inter-rater Pearson correlation")
    fig.colorbar(im, ax=ax)
    return _save(fig, path)


def intra_rater_bars(a: Analysis, path: Path) -> Path | None:
    if a.reliability is None or a.reliability.intra_rater.isna().all():
        return None
    s = a.reliability.intra_rater
    fig = Figure(figsize=(max(4, 0.3 * len(s) + 1.5), 3))
    ax = fig.add_subplot()
    ax.bar(range(len(s)), s.to_numpy(), color="tab:blue")
    ax.set_xticks(range(len(s)), s.index, rotation=90, fontsize=6)
    ax.set_ylim(min(0, float(np.nanmin(s))), 1)
    ax.set_ylabel("mean r between repetitions")
    ax.set_title("intra-rater reliability")
    return _save(fig, path)


def rater_bias(a: Analysis, path: Path) -> Path | None:
    sc = a.scores
    if sc.rater_bias is None:
        return None
    n = len(sc.raters)
    fig = Figure(figsize=(max(5, 0.3 * n + 2), 5))
    x = np.arange(n)
    for k, (val, ci, label) in enumerate((
            (sc.rater_bias, sc.rater_bias_ci, "bias"),
            (sc.rater_inconsistency, sc.rater_inconsistency_ci, "inconsistency"))):
        ax = fig.add_subplot(2, 1, k + 1)
        err = np.abs(np.vstack([val - ci[:, 0], ci[:, 1] - val]))
        ax.errorbar(x, val, yerr=err, fmt="o", capsize=2, ms=4)
        ax.axhline(0, color="0.7", lw=0.8)
        ax.set_ylabel(f"rater {label}")
        ax.set_xticks(x, sc.raters if k else [""] * n, rotation=90, fontsize=6)
    fig.axes[0].set_title(f"rater bias and inconsistency (95% CI)\n{sc.model_name}", fontsize=9)
    return _save(fig, path)


def content_ambiguity(a: Analysis, path: Path) -> Path | None:
    sc = a.scores
    if sc.content_ambiguity is None:
        return None
    n = len(sc.content)
    fig = Figure(figsize=(max(4, 0.4 * n + 2), 3))
    ax = fig.add_subplot()
    val, ci = sc.content_ambiguity, sc.content_ambiguity_ci
    err = np.abs(np.vstack([val - ci[:, 0], ci[:, 1] - val]))
    ax.errorbar(np.arange(n), val, yerr=err, fmt="o", capsize=2)
    ax.set_xticks(np.arange(n), sc.content, rotation=90, fontsize=7)
    ax.set_ylabel("content ambiguity")
    ax.set_title("content ambiguity (95% CI)")
    return _save(fig, path)


def ci_curve(a: Analysis, path: Path) -> Path | None:
    c = a.ci_curve
    if c is None:
        return None
    two = c.dmos_width is not None
    fig = Figure(figsize=(10 if two else 5, 3.6))
    ax = fig.add_subplot(1, 2 if two else 1, 1)
    ax.plot(c.n_raters, c.mean_width, "o", ms=4, label="MOS (subsampled raters)")
    grid = np.linspace(c.n_raters.min(), c.n_raters.max(), 100)
    if np.isfinite(c.a):
        ax.plot(grid, c.a * grid ** (-c.b), "-", label=f"{c.a:.3g} n^-{c.b:.3f}")
    if two:
        ax.plot(c.n_raters, c.dmos_width, "s", ms=4, label="DMOS (paper's curve)")
    ax.set_xlabel("number of raters")
    ax.set_ylabel("mean 95% CI width")
    ax.legend(fontsize=8)
    ax.set_title("CI width versus number of raters", fontsize=10)
    if two:
        ax2 = fig.add_subplot(1, 2, 2)
        red = c.reduction_per_rater()
        n = np.array(list(red), dtype=float)
        r = np.array(list(red.values()))
        ax2.plot(n[r > 0], r[r > 0], "o", ms=4, label="reduction by the n-th rater")
        if np.isfinite(c.decay_rate):
            g = np.linspace(max(5, n.min()), n.max(), 100)
            ax2.plot(g, c.decay_scale * np.exp(-c.decay_rate * g), "-",
                     label=f"{c.decay_scale:.3g} exp(-{c.decay_rate:.3f} n)")
        if (r > 0).sum() >= 2:
            ax2.set_yscale("log")  # an exponential decay is a straight line
            # plain numbers: the default labels are mathtext, which literal_text turns off
            ax2.yaxis.set_major_formatter(LogFormatter(labelOnlyBase=False))
            ax2.yaxis.set_minor_formatter(NullFormatter())
        ax2.set_xlabel("n-th rater added")
        ax2.set_ylabel("DMOS CI width reduction")
        ax2.legend(fontsize=8)
        ax2.set_title("reduction per added participant (paper's reading)", fontsize=10)
    return _save(fig, path)


def split_half_hist(a: Analysis, path: Path) -> Path | None:
    if a.ceiling is None:
        return None
    fig = Figure(figsize=(8, 2.8))
    for k, key in enumerate(("plcc", "srcc", "krcc", "rmse")):
        ax = fig.add_subplot(1, 4, k + 1)
        v = np.asarray(a.ceiling.values[key], dtype=float)
        v = v[np.isfinite(v)]
        if v.size:
            # a tiny panel can give (nearly) the same value in every split: one bin then
            span = float(v.max() - v.min())
            ax.hist(v, bins=30 if span > 1e-9 * max(1.0, float(np.abs(v).max())) else 1,
                    color="tab:gray")
        ax.set_title(f"split-half {key.upper()}", fontsize=9)
    return _save(fig, path)


def metric_comparison(a: Analysis, path: Path) -> Path | None:
    if a.metrics is None:
        return None
    t = a.metrics.table
    fig = Figure(figsize=(max(5, 1.2 * len(t) + 2), 3.8))
    ax = fig.add_subplot()
    x = np.arange(len(t))
    w = 0.38
    for off, key, col in ((-w / 2, "plcc", "tab:blue"), (w / 2, "srcc", "tab:orange")):
        val = t[key].to_numpy(dtype=float)
        lo = t[f"{key}_ci95_low"].to_numpy(dtype=float)
        hi = t[f"{key}_ci95_high"].to_numpy(dtype=float)
        err = np.nan_to_num(np.abs(np.vstack([val - lo, hi - val])))
        bars = ax.bar(x + off, val, w, yerr=err, capsize=3, color=col, label=key.upper())
        for bar, name in zip(bars, t["metric"], strict=True):
            if name in a.metrics.untrained:  # as the benchmark marks them
                bar.set_hatch("//")
                bar.set_alpha(0.5)
    names = ["two half panels\n(2.5-97.5% of splits)" if fit == "none" else
             a.metrics.title(m) + ("\n[FLAGGED]" if m in a.metrics.untrained else "")
             for m, fit in zip(t["metric"], t["fit"], strict=True)]
    ax.set_xticks(x, names, rotation=20, ha="right", fontsize=8)
    for tick, name in zip(ax.get_xticklabels(), t["metric"], strict=True):
        if name in a.metrics.untrained:
            tick.set_color("#a00")
    ax.set_ylim(_lowest(t) - 0.05, 1.05)
    ax.legend(fontsize=8)
    ax.set_title("metrics versus DMOS (95% bootstrap CI; hatched: flagged)", fontsize=10)
    return _save(fig, path)


def metric_benchmark(a: Analysis, path: Path) -> Path | None:
    """Paper-style benchmark: metrics sorted by PLCC, 95% CIs, human ceiling as a band."""
    if a.metrics is None:
        return None
    t = a.metrics.table
    human = t[t["fit"] == "none"]
    t = t[t["fit"] != "none"].sort_values("plcc")
    fig = Figure(figsize=(9, 0.45 * len(t) + 1.8))
    ax = fig.add_subplot()
    y = np.arange(len(t))
    h = 0.38
    for off, key, col in ((h / 2, "plcc", "tab:blue"), (-h / 2, "srcc", "tab:orange")):
        val = t[key].to_numpy(dtype=float)
        err = np.nan_to_num(np.abs(np.vstack([val - t[f"{key}_ci95_low"].to_numpy(float),
                                              t[f"{key}_ci95_high"].to_numpy(float) - val])))
        bars = ax.barh(y + off, val, h, xerr=err, capsize=2, color=col, label=key.upper())
        for bar, name in zip(bars, t["metric"], strict=True):
            if name in a.metrics.untrained:
                bar.set_hatch("//")
                bar.set_alpha(0.5)
    if len(human):
        lo, hi = float(human["plcc_ci95_low"].iloc[0]), float(human["plcc_ci95_high"].iloc[0])
        if np.isfinite(lo) and np.isfinite(hi):
            ax.axvspan(lo, hi, color="0.85", zorder=0,
                       label="two half panels' PLCC\n(2.5-97.5% of splits)")
        bound = a.ceiling.summary()["plcc_full_panel_bound"]["median"] \
            if a.ceiling is not None else float("nan")
        if np.isfinite(bound):
            ax.axvline(bound, color="0.3", ls="--", lw=1, zorder=0,
                       label="ceiling against the\nfull panel's DMOS")
    labels = [a.metrics.title(m) + ("  [FLAGGED]" if m in a.metrics.untrained else "")
              for m in t["metric"]]
    ax.set_yticks(y, labels, fontsize=8)
    for tick, name in zip(ax.get_yticklabels(), t["metric"], strict=True):
        if name in a.metrics.untrained:
            tick.set_color("#a00")
    ax.set_xlim(_lowest(t) - 0.05, 1.0)
    ax.set_xlabel("correlation with DMOS")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.set_title("metric benchmark (95% two-way bootstrap CIs; hatched: flagged)", fontsize=10)
    return _save(fig, path)


def metric_per_method(a: Analysis, path: Path) -> Path | None:
    """SRCC of every metric within each distortion method (heat map with values)."""
    if a.metrics is None or a.metrics.per_method.empty:
        return None
    pm = a.metrics.per_method.pivot(index="metric", columns="method", values="srcc")
    if pm.shape[1] < 2:
        return None
    order = a.metrics.table.set_index("metric")["plcc"].reindex(pm.index).sort_values().index
    pm = pm.loc[order[::-1]]
    fig = Figure(figsize=(1.1 * pm.shape[1] + 3, 0.4 * pm.shape[0] + 1.8))
    ax = fig.add_subplot()
    im = ax.imshow(pm.to_numpy(dtype=float), vmin=-1, vmax=1, cmap="RdBu", aspect="auto")
    for i in range(pm.shape[0]):
        for j in range(pm.shape[1]):
            v = pm.iat[i, j]
            if np.isfinite(v):
                ax.text(j, i, f"{v:.2f}", ha="center", va="center", fontsize=7,
                        color="white" if abs(v) > 0.6 else "black")
    ax.set_xticks(range(pm.shape[1]), pm.columns, rotation=30, ha="right", fontsize=8)
    ax.set_yticks(range(pm.shape[0]), [a.metrics.title(m) for m in pm.index], fontsize=8)
    ax.set_title("SRCC per distortion method", fontsize=10)
    fig.colorbar(im, ax=ax)
    return _save(fig, path)


def rater_agreement(a: Analysis, path: Path) -> Path | None:
    """Each rater's correlation with the others and between their repetitions, thresholds."""
    q = a.quality
    if q is None or "loo_r" not in q.columns or q["loo_r"].isna().all():
        return None
    n = len(q)
    fig = Figure(figsize=(max(5, 0.32 * n + 2), 3.4))
    ax = fig.add_subplot()
    x = np.arange(n)
    status = q["status"].astype(str).to_numpy()
    colors = np.where(status == "used", "tab:blue",
                      np.where(np.char.startswith(status.astype(str), "removed"), "tab:red",
                               "0.6"))
    ax.bar(x - 0.2, q["loo_r"].to_numpy(dtype=float), 0.4, color=colors,
           label="r with all others (blue used, red removed, grey dropped)")
    ax.axhline(THRESHOLDS["loo_r"], color="tab:blue", ls="--", lw=0.8)
    if "repeat_r" in q.columns and q["repeat_r"].notna().any():  # its threshold only with it
        ax.bar(x + 0.2, q["repeat_r"].to_numpy(dtype=float), 0.4, color="tab:green",
               alpha=0.6, label="r between own repetitions")
        ax.axhline(THRESHOLDS["repeat_r"], color="tab:green", ls=":", lw=0.8)
    ax.axhline(0, color="0.5", lw=0.6)
    ax.set_xticks(x, q.index, rotation=90, fontsize=6)
    ax.set_ylim(min(-0.5, float(np.nanmin(q["loo_r"].to_numpy(float))) - 0.05), 1.0)
    ax.legend(fontsize=7, loc="lower left")
    ax.set_title("rater agreement (dashed: flag thresholds)", fontsize=10)
    return _save(fig, path)


def _scene_order(rs: RatingSet) -> tuple[np.ndarray, list[tuple[str, float]], np.ndarray]:
    """Stimulus rows grouped by scene (hidden reference first, then by method and level),
    each scene's label position, and the rows' x positions with a gap between scenes."""
    st = rs.stimuli.reset_index(drop=True)
    scenes = list(dict.fromkeys(st["scene"].astype(str)))
    rows, xs, labels = [], [], []
    x = 0.0
    for scene in scenes:
        group = st[st["scene"].astype(str) == scene]
        group = group.assign(_ref=~group["is_hidden_reference"].astype(bool)).sort_values(
            ["_ref", "method", "level"], na_position="first", kind="stable")
        start = x
        for k in group.index:
            rows.append(int(k))
            xs.append(x)
            x += 1.0
        labels.append((scene, (start + x - 1.0) / 2.0))
        x += 1.0  # the gap between scenes
    return np.array(rows, dtype=int), labels, np.array(xs)


def ratings_per_stimulus(a: Analysis, path: Path) -> Path | None:
    """Ratings each stimulus got, grouped by scene, hidden references marked (only when the
    design gives stimuli different numbers of ratings: a full design's bars are all equal)."""
    rs = a.screened
    counts = rs.ratings_per_stimulus()
    if counts.size == 0 or counts.min() == counts.max():
        return None
    rows, labels, x = _scene_order(rs)
    hidden = rs.hidden_reference_mask[rows]
    y = counts[rows]
    fig = Figure(figsize=(min(18.0, max(7.0, 0.12 * x.size + 2.5)), 4.0))
    ax = fig.add_subplot()
    ax.bar(x[~hidden], y[~hidden], 0.85, color="tab:blue", label="distorted stimulus")
    ax.bar(x[hidden], y[hidden], 0.85, color="tab:orange", hatch="//", edgecolor="0.3",
           lw=0.4, label="hidden reference")
    if rs.allocation == "adaptive":
        ax.axhline(rs.n_raters, color="0.3", ls="--", lw=0.8,
                   label=f"block 1: one per rater ({rs.n_raters})")
    med = float(np.median(counts))
    ax.axhline(med, color="tab:green", ls=":", lw=1.0, label=f"median ({med:g})")
    ax.set_ylim(0, float(y.max()) * 1.22)
    for name, pos in labels:  # scene names above their group
        ax.text(pos, float(y.max()) * 1.04, name, ha="center", va="bottom", fontsize=7,
                rotation=90 if len(labels) > 12 else 0)
    st = rs.stimuli.iloc[rows]
    ax.set_xticks(x, ["ref" if h else f"{str(m)[:6]}{'' if pd.isna(lv) else int(lv)}"
                      for m, lv, h in zip(st["method"], st["level"], hidden, strict=True)],
                  rotation=90, fontsize=6 if x.size <= 150 else 4)
    ax.set_xlim(-1.0, float(x.max()) + 1.0)
    ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_ylabel("ratings")
    ax.set_title(f"ratings per stimulus, {rs.allocation} design (min {counts.min()}, "
                 f"median {med:g}, max {counts.max()})", fontsize=10)
    ax.legend(fontsize=7, loc="lower center", bbox_to_anchor=(0.5, 1.08), ncol=4,
              frameon=False)
    return _save(fig, path)


def panel_survey(a: Analysis, path: Path) -> Path | None:
    if a.panel is None or a.ratings.panel is None or a.ratings.panel.definition is None:
        return None
    return draw_survey(a.panel, a.ratings.panel.definition, path)


FIGURES = {
    "metric_benchmark": (metric_benchmark, "metric benchmark: PLCC and SRCC with 95% two-way "
                         "bootstrap CIs, sorted{ceiling}; flagged metrics (random backbone, "
                         "uniform weights) hatched"),
    "metric_per_method": (metric_per_method, "SRCC of each metric within each distortion "
                          "method"),
    "rater_agreement": (rater_agreement, "each rater's correlation with the mean of all "
                        "other raters read (the data-quality table's r others; the "
                        "screening's r1 uses only the raters kept){repeats}, with the flag "
                        "thresholds"),
    "ratings_per_stimulus": (ratings_per_stimulus, "ratings per stimulus after screening, "
                             "grouped by scene (hatched: hidden references); in an adaptive "
                             "design block 1 gives every stimulus one rating per rater and "
                             "later blocks go to the stimuli with the widest DMOS intervals"),
    "dmos_per_scene": (dmos_per_scene, "DMOS per scene with 95% CIs by method and level"
                       "{metrics}"),
    "metric_scatter": (metric_scatter, "each metric against DMOS with its fitted mapping"),
    "metric_comparison": (metric_comparison, "metric comparison: PLCC and SRCC with 95% "
                          "bootstrap CIs{ceiling}"),
    "inter_rater": (inter_rater_heatmap, "inter-rater Pearson correlation"),
    "intra_rater": (intra_rater_bars, "intra-rater reliability (mean r between repetitions)"),
    "rater_bias": (rater_bias, "rater bias and inconsistency with 95% CIs{split}"),
    "content_ambiguity": (content_ambiguity, "content ambiguity with 95% CIs{split}"),
    "split_half": (split_half_hist, "split-half (human ceiling) distributions"),
    "ci_vs_raters": (ci_curve, "left: mean 95% CI width of MOS (power-law fit) and of DMOS "
                     "versus the number of raters (random panels); right: the DMOS CI "
                     "reduction bought by each added participant, with its exponential decay "
                     "(the CGVQM+D paper's reading)"),
    "panel_survey": (panel_survey, "the Likert questions of the participants' questionnaires: "
                     "share of each answer, disagreement left of zero and agreement right; "
                     "n = participants who chose a point"),
}
"""Each figure's drawing function and caption; ``{ceiling}`` in a caption is
:data:`CEILING_NOTES`' text for it where the human ceiling is drawn, and nothing where not."""
CEILING_NOTES = {"metric_benchmark": "; the grey band is the agreement of two half panels "
                                     "and the dashed line the PLCC a perfect metric would "
                                     "reach against the full panel's DMOS",
                 "metric_comparison": ", and the agreement of two half panels (its whiskers: "
                                      "2.5-97.5% of the splits)"}
SPLIT_NOTE = ("; the score model identifies only inconsistency\u00b2 + ambiguity\u00b2 of each "
              "rating: a constant can move from every rater's inconsistency\u00b2 to every "
              "content's ambiguity\u00b2 without changing the fit, so compare raters (and "
              "contents) with each other, not with an absolute level; an estimate at 0 sits "
              "at that boundary and has no CI")
"""``{split}`` in a caption, where the model has both rater inconsistency and content
ambiguity (SUREAL's full MLE)."""
METRICS_NOTE = (" (metric predictions after the logistic mapping as hollow black markers, "
                "side by side to the right of each DMOS in the legend's order)")
"""``{metrics}`` in a caption, where metric scores were given and are drawn."""
REPEATS_NOTE = " and between their own repetitions"
"""``{repeats}`` in a caption, where raters rated stimuli more than once (bars drawn)."""


def literal_text() -> contextlib.AbstractContextManager:
    """Text drawn as written: scene, method, metric and rater names are free text, and
    matplotlib would read a ``$...$`` pair in one as mathtext (garbled, or a parse error
    that stopped the whole report)."""
    return rc_context({"text.parse_math": False})


def draw_all(a: Analysis, folder: Path) -> dict[str, tuple[Path, str]]:
    """Draw every figure that applies; returns name -> (png path, caption)."""
    folder.mkdir(parents=True, exist_ok=True)
    out = {}
    with literal_text():
        for name, (fn, caption) in FIGURES.items():
            path = fn(a, folder / f"{name}.png")
            if path is not None:  # captions say only what is drawn
                note = CEILING_NOTES.get(name, "") if a.ceiling is not None else ""
                split = SPLIT_NOTE if a.scores.content_ambiguity is not None else ""
                drawn = METRICS_NOTE if a.metrics is not None and a.metrics.data else ""
                q = a.quality
                repeats = REPEATS_NOTE if q is not None and "repeat_r" in q.columns and \
                    q["repeat_r"].notna().any() else ""
                out[name] = (path, caption.replace("{ceiling}", note).replace("{split}", split)
                             .replace("{metrics}", drawn).replace("{repeats}", repeats))
    return out
