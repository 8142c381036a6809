"""Cheap full-reference baselines for the demo: PSNR and SSIM, vectorised over whole videos.

PSNR is computed on RGB over the whole video (one MSE over all frames and channels). SSIM is
Wang et al. (2004) on the luma channel (BT.601 weights), Gaussian window sigma 1.5,
K1 = 0.01, K2 = 0.03, L = 255, averaged over pixels and then over frames. Scores are written
in the metric-score CSV contract (stimulus, reference, metric, score) for the conditions of a
manifest (hidden references are left out: their score is trivially perfect).

Usage: python scripts/demo_baselines.py --manifest STUDY/manifest.json --out baselines.csv
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np
from scipy import ndimage
from tqdm.auto import tqdm

from stimuli_manifests import StimuliError, load_manifest, read_video

PSNR_CAP_DB = 100.0
SSIM_SIGMA = 1.5
SSIM_K1, SSIM_K2, SSIM_L = 0.01, 0.03, 255.0


def psnr(ref: np.ndarray, test: np.ndarray) -> float:
    """PSNR in dB of uint8 videos (T, H, W, 3); identical videos give PSNR_CAP_DB."""
    mse = float(np.mean((ref.astype(np.float64) - test.astype(np.float64)) ** 2))
    if mse == 0.0:
        return PSNR_CAP_DB
    return min(PSNR_CAP_DB, 10.0 * np.log10(255.0**2 / mse))


def _luma(video: np.ndarray) -> np.ndarray:
    v = video.astype(np.float64)
    return 0.299 * v[..., 0] + 0.587 * v[..., 1] + 0.114 * v[..., 2]


def ssim(ref: np.ndarray, test: np.ndarray) -> float:
    """Mean SSIM over frames of the luma of uint8 videos (T, H, W, 3)."""
    x, y = _luma(ref), _luma(test)
    sigma = (0.0, SSIM_SIGMA, SSIM_SIGMA)  # no filtering across time

    def blur(a: np.ndarray) -> np.ndarray:
        return ndimage.gaussian_filter(a, sigma=sigma, mode="reflect", truncate=3.5)

    mx, my = blur(x), blur(y)
    vxx = blur(x * x) - mx * mx
    vyy = blur(y * y) - my * my
    vxy = blur(x * y) - mx * my
    c1, c2 = (SSIM_K1 * SSIM_L) ** 2, (SSIM_K2 * SSIM_L) ** 2
    s = ((2 * mx * my + c1) * (2 * vxy + c2)) / ((mx * mx + my * my + c1) * (vxx + vyy + c2))
    return float(s.mean(axis=(1, 2)).mean())


def score_manifest(manifest: str | Path, *, progress: bool = True) -> list[dict[str, object]]:
    """PSNR and SSIM rows for every condition of the manifest."""
    loaded = load_manifest(manifest)
    m = loaded.manifest
    refs: dict[str, np.ndarray] = {}
    rows: list[dict[str, object]] = []
    for cond in tqdm(m.conditions, desc="baselines", unit="video", disable=not progress):
        if cond.reference not in refs:
            refs[cond.reference] = read_video(loaded.reference_path(cond.reference))
        ref = refs[cond.reference]
        test = read_video(loaded.resolve(cond.path))
        if test.shape != ref.shape:
            raise StimuliError(f"{cond.id}: shape {test.shape} differs from its reference "
                               f"{cond.reference} {ref.shape}")
        for metric, value in (("PSNR", psnr(ref, test)), ("SSIM", ssim(ref, test))):
            rows.append({"stimulus": cond.id, "reference": cond.reference, "metric": metric,
                         "score": value})
    return rows


def write_scores(rows: list[dict[str, object]], out: str | Path) -> Path:
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out, "w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=["stimulus", "reference", "metric", "score"])
        writer.writeheader()
        writer.writerows(rows)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--manifest", required=True)
    parser.add_argument("--out", required=True)
    args = parser.parse_args(argv)
    try:
        path = write_scores(score_manifest(args.manifest), args.out)
    except StimuliError as exc:
        print(f"demo_baselines: error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
