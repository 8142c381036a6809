"""The calibration objectives written plainly in torch: the definition the fast fit must match.

:mod:`.fitting` computes the same losses and their gradients by hand (for speed); the tests
compare both, and this module is the readable statement of what is minimised.
"""

from __future__ import annotations

import torch


def pearson(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Pearson's linear correlation of two 1-d tensors, differentiable."""
    dx = x - x.mean()
    dy = y - y.mean()
    return (dx * dy).sum() / torch.sqrt((dx * dx).sum() * (dy * dy).sum())


def pooled_scores(M: torch.Tensor, counts: torch.Tensor, omega: torch.Tensor,
                  alpha: torch.Tensor, pooling: str = "max") -> torch.Tensor:
    """s_v = alpha * pool_p sum_c |omega_c| M[v, p, c] over each video's real patches."""
    e = M @ omega.abs()  # (V, P)
    valid = torch.arange(M.shape[1])[None, :] < counts[:, None]
    if pooling == "max":
        pooled = torch.where(valid, e, torch.full_like(e, -torch.inf)).amax(dim=1)
    else:
        pooled = (e * valid).sum(dim=1) / counts.to(e.dtype)
    return alpha * pooled


def calibration_loss(M: torch.Tensor, counts: torch.Tensor, y: torch.Tensor,
                     groups: torch.Tensor, omega: torch.Tensor, alpha: torch.Tensor, *,
                     objective: str = "plcc", pooling: str = "max") -> torch.Tensor:
    """Sum over datasets of 1 - |PLCC(s, y)| ("plcc", upstream), of 1 - PLCC(100 - s, y)
    ("plcc-signed") or of the MSE between q = 100 - s and y divided by var(y) ("nmse")."""
    s = pooled_scores(M, counts, omega, alpha, pooling)
    total = s.new_zeros(())
    for d in torch.unique(groups):
        sel = groups == d
        if objective == "plcc":
            total = total + 1.0 - pearson(s[sel], y[sel]).abs()
        elif objective == "plcc-signed":
            total = total + 1.0 - pearson(100.0 - s[sel], y[sel])
        else:
            yd = y[sel]
            total = total + ((100.0 - s[sel] - yd) ** 2).mean() / yd.var(unbiased=False)
    return total
