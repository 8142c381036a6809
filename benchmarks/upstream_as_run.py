"""A same-machine stand-in for the authors' ``run_cgvqm`` as its users run it (benchmarks only).

torchvision, which the authors' script needs, cannot be imported next to this project's
torch, so the benchmarks time this stand-in instead. It does what upstream's scoring loop
does, step by step (the facts of its data flow, written anew here):

- both whole videos are turned into normalised float32 tensors on the host first, padded
  by replication to whole clips and patches;
- for every clip, row and column, the test patch and the reference patch are sliced from
  those host tensors and copied to the device separately (float32, from pageable memory);
- each goes through the network on its own (batch 1), stage by stage, test then reference,
  in PyTorch's default layout with batch norm as a separate operation (torchvision's
  r3d_18), with PyTorch's default precision switches on the device (TF32 convolutions on
  CUDA, no cuDNN benchmark mode), under ``no_grad``;
- every level adds its weighted mean squared difference and its trilinearly interpolated
  error map, and the patch's error map is written into a host tensor (a copy back and a
  synchronisation per patch);
- q is 100 minus the largest (or mean) patch error.

What it leaves out, so that it is never slower than the real thing: building the model
(upstream loads the backbone and the weights at every call) and reading the files (both
sides get the same in-memory frames).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from cgvqm_core.features import MEAN, STD, FeatureNet
from cgvqm_core.hub import Backbone
from cgvqm_core.weights import FeatureWeights


@dataclass
class UpstreamRun:
    q_max: float
    q_mean: float
    seconds: float

    def quality(self, pool: str) -> float:
        return self.q_max if pool == "max" else self.q_mean


class UpstreamAsRun:
    """The stand-in, with its network built once (see the module docstring)."""

    def __init__(self, backbone: Backbone, weights: FeatureWeights, device: str = "cpu",
                 patch_scale: int = 4) -> None:
        self.device = torch.device(device)
        precision = "tf32" if self.device.type == "cuda" else "fp32"
        self.net = FeatureNet(backbone, weights.n_levels, device=device, precision=precision,
                              fuse_bn=False, channels_last=False, cudnn_benchmark=False)
        self.w = [torch.as_tensor(w, dtype=torch.float32, device=self.device).view(1, -1, 1, 1, 1)
                  for w in weights.level_weights()]
        self.alpha = float(weights.alpha)
        self.patch_scale = patch_scale

    def _host_video(self, frames: np.ndarray) -> torch.Tensor:
        x = torch.from_numpy(frames).permute(3, 0, 1, 2).float().div(255)  # (3, T, H, W)
        mean = torch.tensor(MEAN).view(3, 1, 1, 1)
        std = torch.tensor(STD).view(3, 1, 1, 1)
        return ((x - mean) / std).unsqueeze(0)

    def score(self, ref: np.ndarray, test: np.ndarray, fps: float = 30.0) -> UpstreamRun:
        t0 = time.perf_counter()
        D, R = self._host_video(test), self._host_video(ref)
        T, H, W = R.shape[2:]
        ph, pw = int(H / self.patch_scale), int(W / self.patch_scale)
        clip = int(min(fps, 30))
        pad = (0, (pw - W % pw) % pw, 0, (ph - H % ph) % ph, 0, (clip - T % clip) % clip)
        D = F.pad(D, pad, mode="replicate")
        R = F.pad(R, pad, mode="replicate")
        emap = torch.zeros(R.shape[2:])
        errors = []
        for i in range(0, D.shape[2], clip):
            for h in range(0, D.shape[3], ph):
                for w in range(0, D.shape[4], pw):
                    sl = (slice(None), slice(None), slice(i, i + clip), slice(h, h + ph),
                          slice(w, w + pw))
                    cd, cr = D[sl].to(self.device), R[sl].to(self.device)
                    with torch.no_grad():
                        q, em = self._patch(cd, cr)
                    emap[i:i + clip, h:h + ph, w:w + pw] = em.squeeze()
                    errors.append(q)
        q_max = 100 - float(max(errors))
        q_mean = 100 - float(torch.mean(torch.stack(errors)))
        if self.device.type == "cuda":
            torch.cuda.synchronize(self.device)
        return UpstreamRun(q_max, q_mean, time.perf_counter() - t0)

    def _patch(self, x: torch.Tensor, y: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        gx, gy = self.net.levels(x), self.net.levels(y)
        diff = torch.zeros((), device=self.device)
        emap = torch.zeros(1, 1, *x.shape[2:], device=self.device)
        for wl in self.w:
            a, b = next(gx), next(gy)  # test's stage, then the reference's
            d = (a - b).pow(2)
            diff = diff + (wl * d.mean([2, 3, 4], keepdim=True)).sum()
            e = (wl * d).sum(1, keepdim=True)
            emap = emap + F.interpolate(e, size=tuple(x.shape[2:]), mode="trilinear")
        for g in (gy, gx):  # last in, first out: each restores the switches it found
            for _ in g:
                pass
        return self.alpha * diff, self.alpha * emap
