"""Generated studies with known truth, for tests, benchmarks and planning a panel size.

Each rater s rates stimulus v as ``clip(Q(v) + bias_s + N(0, noise_s^2))`` on the manifest
scale; outlier raters rate at random. Raters of a known kind can be injected (``special``):

- ``random``: uniform on the scale, ignoring the stimulus;
- ``inverted``: ``100 - Q(v)`` plus the usual noise (the scale read backwards);
- ``offset:D``: a consistent rater whose every rating is shifted by D;
- ``partial:F``: a consistent rater who answered only the first share F of their trials;
- ``noisy:SD``: a consistent rater with noise s.d. SD.

The truth (Q, biases, who is an outlier, each special rater's kind) is returned.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from stimuli_manifests import LoadedManifest, Manifest, parse_manifest


@dataclass
class SyntheticStudy:
    manifest: LoadedManifest
    ratings: pd.DataFrame  # tidy ratings table (cgvq-ratings/1, docs/file-formats.md; main columns)
    quality: pd.Series  # true quality per stimulus id
    bias: pd.Series  # true bias per rater
    outliers: list[str]
    kinds: dict[str, str] | None = None  # injected raters -> their kind


def synthetic_manifest(n_scenes: int = 10, methods: tuple[str, ...] = ("blur", "noise"),
                       levels: int = 3, *, repetitions: int = 3) -> Manifest:
    """A manifest of ``n_scenes`` references x methods x levels (paths are never read)."""
    refs = [{"id": f"SRC{i + 1:02d}", "path": f"src{i + 1:02d}.mkv", "scene": f"scene{i + 1}"}
            for i in range(n_scenes)]
    conds = [{"reference": r["id"], "path": f"{r['id']}_{m}{lv}.mkv", "method": m, "level": lv}
             for r in refs for m in methods for lv in range(1, levels + 1)]
    return parse_manifest({"format": "cgvq-manifest/1", "study_id": "synthetic",
                           "protocol": {"repetitions": repetitions},
                           "references": refs, "conditions": conds})


def synthetic_study(
    n_scenes: int = 10,
    methods: tuple[str, ...] = ("blur", "noise"),
    levels: int = 3,
    n_raters: int = 20,
    repetitions: int = 3,
    *,
    bias_sd: float = 5.0,
    noise_sd: float = 8.0,
    n_outliers: int = 0,
    seed: int = 0,
    special: dict[str, str] | None = None,
    study_id: str = "synthetic",
) -> SyntheticStudy:
    """Ratings of a generated panel; ``noise_sd = 0`` and ``bias_sd = 0`` give exact truth.

    ``special`` maps extra rater ids to a kind (module docstring); they come after the
    ``n_raters`` regular raters."""
    rng = np.random.default_rng(seed)
    manifest = synthetic_manifest(n_scenes, methods, levels, repetitions=repetitions)
    stimuli = manifest.stimuli()
    q = {}
    ref_q = {r.id: rng.uniform(70, 85) for r in manifest.references}
    method_k = {m: rng.uniform(8, 14) for m in methods}
    for s in stimuli:
        if s.is_hidden_reference:
            q[s.id] = ref_q[s.id]
        else:
            q[s.id] = ref_q[s.reference] - method_k[s.method] * (levels + 1 - s.level) \
                + rng.normal(0, 3)
    special = dict(special or {})
    raters = [f"P{i + 1:02d}" for i in range(n_raters)]
    bias = rng.normal(0, bias_sd, n_raters) if bias_sd > 0 else np.zeros(n_raters)
    bias -= bias.mean()
    outliers = raters[:n_outliers]
    extra_bias = []
    for name, kind in special.items():
        raters.append(name)
        extra_bias.append(float(kind.split(":")[1]) if kind.startswith("offset:") else 0.0)
    bias = np.concatenate([bias, extra_bias])
    rows = []
    for k, rater in enumerate(raters):
        kind = special.get(rater, "random" if rater in outliers else "regular")
        sd = float(kind.split(":")[1]) if kind.startswith("noisy:") else noise_sd
        share = float(kind.split(":")[1]) if kind.startswith("partial:") else 1.0
        order = [(rep, stimuli[i]) for rep in range(1, repetitions + 1)
                 for i in rng.permutation(len(stimuli))]
        for trial, (rep, s) in enumerate(order[: max(1, round(share * len(order)))]):
            noise = rng.normal(0, sd) if sd else 0.0
            if kind == "random":
                value = rng.uniform(0, 100)
            elif kind == "inverted":
                value = 100.0 - q[s.id] + noise
            else:
                value = q[s.id] + bias[k] + noise
            rows.append({"study": study_id, "session": f"{rater}-s1", "participant": rater,
                         "trial": trial, "stimulus": s.id, "reference": s.reference,
                         "repetition": rep, "is_hidden_reference": s.is_hidden_reference,
                         "rating": float(np.clip(value, 0, 100))})
    if study_id != "synthetic":
        manifest = manifest.model_copy(update={"study_id": study_id})
    loaded = LoadedManifest(manifest, None, Path("."))
    return SyntheticStudy(loaded, pd.DataFrame(rows), pd.Series(q), pd.Series(bias, raters),
                          outliers, special)
