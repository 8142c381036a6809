"""Novel-view-style reconstruction: the image approximated by a set of Gaussian splats.

At every keyframe the splats are refitted: centres drawn (seeded) on a jittered grid,
colours from the low-passed reference at the centre. Between
keyframes the splats move with the renderer's motion vectors and keep their colours. The
image is the normalised sum of the splats (normalised convolution), so fewer splats give
more blur, and refitting gives popping.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage


def _bilinear_at(img: np.ndarray, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    coords = np.stack([ys - 0.5, xs - 0.5])
    if img.ndim == 2:
        return ndimage.map_coordinates(img, coords, order=1, mode="nearest")
    return np.stack(
        [ndimage.map_coordinates(img[..., c], coords, order=1, mode="nearest")
         for c in range(img.shape[-1])],
        axis=-1,
    )


def splat_sigma(width: int, height: int, n_splats: int) -> float:
    """Gaussian radius (pixels) for ``n_splats`` splats covering the frame: half the spacing."""
    return 0.5 * float(np.sqrt(width * height / n_splats))


def fit_splats(ref: np.ndarray, n_splats: int, sigma: float, rng: np.random.Generator):
    """Centres (x, y in pixels) and colours of about ``n_splats`` splats for one keyframe.

    Centres are stratified (one at a random place in each cell of a grid with the splat
    spacing), colours are the reference low-passed over the splat's footprint.
    """
    h, w = ref.shape[:2]
    spacing = float(np.sqrt(w * h / n_splats))
    nx, ny = max(1, round(w / spacing)), max(1, round(h / spacing))
    gy, gx = np.mgrid[0:ny, 0:nx]
    xs = ((gx.ravel() + rng.random(gx.size)) * (w / nx)).astype(np.float64)
    ys = ((gy.ravel() + rng.random(gy.size)) * (h / ny)).astype(np.float64)
    lowpass = ndimage.gaussian_filter(ref, sigma=(0.5 * sigma, 0.5 * sigma, 0), mode="nearest")
    return xs, ys, _bilinear_at(lowpass, xs, ys)


def render_splats(xs: np.ndarray, ys: np.ndarray, colours: np.ndarray, width: int,
                  height: int, sigma: float) -> np.ndarray:
    """Normalised Gaussian splatting: sum(w_i c_i) / sum(w_i) on the pixel grid."""
    num = np.zeros((height, width, 3), dtype=np.float64)
    den = np.zeros((height, width), dtype=np.float64)
    fx, fy = xs - 0.5, ys - 0.5
    x0, y0 = np.floor(fx).astype(int), np.floor(fy).astype(int)
    ax, ay = fx - x0, fy - y0
    for oy, wy in ((0, 1.0 - ay), (1, ay)):
        for ox, wx in ((0, 1.0 - ax), (1, ax)):
            cx, cy = x0 + ox, y0 + oy
            ok = (cx >= 0) & (cx < width) & (cy >= 0) & (cy < height)
            wgt = (wx * wy)[ok]
            np.add.at(den, (cy[ok], cx[ok]), wgt)
            np.add.at(num, (cy[ok], cx[ok]), wgt[:, None] * colours[ok])
    num = ndimage.gaussian_filter(num, sigma=(sigma, sigma, 0), mode="constant")
    den = ndimage.gaussian_filter(den, sigma=sigma, mode="constant")
    fallback = colours.mean(axis=0) if len(colours) else np.zeros(3)
    out = np.where(den[..., None] > 1e-6, num / np.maximum(den, 1e-12)[..., None], fallback)
    return out.astype(np.float32)


def splat_sequence(refs: list[np.ndarray], motions: list[np.ndarray], n_splats: int,
                   keyframe_interval: int, rng: np.random.Generator) -> list[np.ndarray]:
    """Splat approximation of every frame; ``motions[i]`` maps frame i back to frame i-1."""
    h, w = refs[0].shape[:2]
    sigma = splat_sigma(w, h, n_splats)
    out = []
    xs = ys = colours = None
    for i, ref in enumerate(refs):
        if i % keyframe_interval == 0:
            xs, ys, colours = fit_splats(ref, n_splats, sigma, rng)
        else:
            # motion at the splat's (approximate) new place points back to where it was
            mv = _bilinear_at(motions[i], xs, ys)
            xs, ys = xs - mv[:, 0], ys - mv[:, 1]
        out.append(render_splats(xs, ys, colours, w, h, sigma))
    return out
