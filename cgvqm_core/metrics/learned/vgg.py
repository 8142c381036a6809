"""VGG-16 (Simonyan & Zisserman 2015) in plain PyTorch, with torchvision's module names.

``features`` is the same ``nn.Sequential`` of 31 modules as torchvision's ``vgg16().features``
(convolution, ReLU and max-pooling at the same indices), ``avgpool`` and ``classifier``
follow, so torchvision's ImageNet checkpoint ``vgg16-397923af.pth`` loads with
``load_state_dict(strict=True)`` without importing torchvision. The perceptual metrics use
only ``features``; ``pool="l2"`` puts DISTS's L2 pooling at the pooling indices (no
parameters, so the state dict is unchanged).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence

import torch
from torch import nn

#: torchvision's configuration "D": channels of each 3x3 convolution, "M" = 2x2 pooling
CONFIG: tuple[int | str, ...] = (64, 64, "M", 128, 128, "M", 256, 256, 256, "M",
                                 512, 512, 512, "M", 512, 512, 512, "M")
#: indices in ``features`` of the ReLUs LPIPS and DISTS compare (relu1_2 ... relu5_3)
TAPS = (3, 8, 15, 22, 29)
TAP_CHANNELS = (64, 128, 256, 512, 512)
POOL_INDICES = (4, 9, 16, 23, 30)


def make_features(pool: Callable[[], nn.Module] | None = None) -> nn.Sequential:
    """torchvision's ``vgg16().features``; ``pool`` replaces its max-pooling modules."""
    layers: list[nn.Module] = []
    cin = 3
    for v in CONFIG:
        if v == "M":
            layers.append(pool() if pool else nn.MaxPool2d(kernel_size=2, stride=2))
        else:
            layers += [nn.Conv2d(cin, int(v), kernel_size=3, padding=1), nn.ReLU(inplace=True)]
            cin = int(v)
    return nn.Sequential(*layers)


class VGG16(nn.Module):
    """torchvision's VGG-16 (no batch norm); ``classifier=False`` builds ``features`` only."""

    def __init__(self, *, classifier: bool = True, num_classes: int = 1000,
                 pool: Callable[[], nn.Module] | None = None) -> None:
        super().__init__()
        self.features = make_features(pool)
        if classifier:
            self.avgpool = nn.AdaptiveAvgPool2d((7, 7))
            self.classifier = nn.Sequential(
                nn.Linear(512 * 7 * 7, 4096), nn.ReLU(True), nn.Dropout(p=0.5),
                nn.Linear(4096, 4096), nn.ReLU(True), nn.Dropout(p=0.5),
                nn.Linear(4096, num_classes))
        init_like_torchvision(self)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.features(x)
        if not hasattr(self, "classifier"):
            return x
        return self.classifier(torch.flatten(self.avgpool(x), 1))


def init_like_torchvision(model: nn.Module) -> None:
    """torchvision's VGG initialisation (He normal for convolutions, N(0, 0.01) for linear)."""
    for m in model.modules():
        if isinstance(m, nn.Conv2d):
            nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
            if m.bias is not None:
                nn.init.constant_(m.bias, 0)
        elif isinstance(m, nn.Linear):
            nn.init.normal_(m.weight, 0, 0.01)
            nn.init.constant_(m.bias, 0)


def tapped(features: nn.Sequential, x: torch.Tensor, taps: Sequence[int]
           ) -> Iterator[torch.Tensor]:
    """Run ``features`` up to its last tap, yielding the output of each tapped module."""
    want = set(taps)
    for i, module in enumerate(features):
        x = module(x)
        if i in want:
            yield x
            if i == max(taps):
                return


def expected_keys(*, classifier: bool = True) -> dict[str, tuple[int, ...]]:
    """Name -> shape of every state-dict entry (built on the 'meta' device: no memory)."""
    with torch.device("meta"):
        model = VGG16(classifier=classifier)
    return {k: tuple(v.shape) for k, v in model.state_dict().items()}
