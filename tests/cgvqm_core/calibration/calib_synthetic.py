"""Synthetic calibration data whose true channel weights are known (for the tests)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd


@dataclass
class Synthetic:
    M: np.ndarray  # (V, P, N) float32
    counts: np.ndarray  # (V,)
    true_w: np.ndarray  # (N,) the weights the "humans" use
    quality: np.ndarray  # (V,) noiseless human score, 0..100 (quality direction)
    dmos: np.ndarray  # (V,) with rater noise
    items: pd.DataFrame  # dataset, stimulus, scene, target, ...


def make(n_scenes: int = 12, per_scene: int = 10, n_patches: int = 8, n_channels: int = 40,
         noise: float = 3.0, seed: int = 0, dataset: str = "synth",
         ragged: bool = True) -> Synthetic:
    """Videos of ``n_scenes`` scenes; each video's patches carry a distortion whose channel
    profile mixes channels humans weigh (true_w > 0) with loud nuisance channels (true_w = 0,
    large values), so uniform weights are a poor metric and the true weights a good one.
    Human quality = 100 - 40 * max_p (m_p . true_w) / scale, plus Gaussian noise."""
    rng = np.random.default_rng(seed)
    N = n_channels
    true_w = np.zeros(N)
    relevant = rng.choice(N, size=N // 4, replace=False)
    true_w[relevant] = rng.uniform(0.5, 2.0, size=relevant.size)
    V = n_scenes * per_scene
    scene_gain = rng.uniform(0.5, 2.0, size=n_scenes)  # content masks the nuisance channels
    M = np.zeros((V, n_patches, N), dtype=np.float32)
    counts = np.full(V, n_patches)
    rows = []
    for v in range(V):
        s = v // per_scene
        if ragged:
            counts[v] = rng.integers(n_patches // 2, n_patches + 1)
        severity = rng.uniform(0.05, 1.0)
        intensity = severity * np.exp(rng.normal(0, 0.5, counts[v]))
        signal = rng.gamma(2.0, 0.5, N) * (true_w > 0)
        nuisance = rng.gamma(2.0, 0.5, N) * (true_w == 0) * scene_gain[s] * 3.0 \
            * rng.uniform(0.2, 1.0)
        for p in range(counts[v]):
            jitter = rng.gamma(8.0, 1 / 8.0, N)
            M[v, p] = (intensity[p] * signal * jitter
                       + nuisance * rng.uniform(0.5, 1.5) * jitter)
        rows.append({"dataset": dataset, "stimulus": f"S{s:02d}_V{v:03d}",
                     "reference": f"S{s:02d}", "scene": f"scene{s:02d}"})
    err = np.array([(M[v, : counts[v]].astype(np.float64) @ true_w).max() for v in range(V)])
    quality = 100.0 - 80.0 * err / err.max()
    dmos = quality + rng.normal(0, noise, V)
    items = pd.DataFrame(rows)
    items["dmos"] = dmos
    items["target"] = np.clip(dmos, 0, 100)
    return Synthetic(M, counts, true_w, quality, dmos, items)
