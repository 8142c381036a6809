"""AlexNet (Krizhevsky et al. 2012, torchvision's "one weird trick" variant) in plain PyTorch.

Module names and layout equal torchvision's ``alexnet()`` so its ImageNet checkpoint
``alexnet-owt-7be5be79.pth`` loads with ``load_state_dict(strict=True)``. LPIPS's default
network (``lpips-alex``) compares the five ReLU outputs of ``features``.
"""

from __future__ import annotations

import torch
from torch import nn

#: indices in ``features`` of the ReLUs LPIPS compares (relu1 ... relu5)
TAPS = (1, 4, 7, 9, 11)
TAP_CHANNELS = (64, 192, 384, 256, 256)


def make_features() -> nn.Sequential:
    """torchvision's ``alexnet().features``."""
    return nn.Sequential(
        nn.Conv2d(3, 64, kernel_size=11, stride=4, padding=2), nn.ReLU(inplace=True),
        nn.MaxPool2d(kernel_size=3, stride=2),
        nn.Conv2d(64, 192, kernel_size=5, padding=2), nn.ReLU(inplace=True),
        nn.MaxPool2d(kernel_size=3, stride=2),
        nn.Conv2d(192, 384, kernel_size=3, padding=1), nn.ReLU(inplace=True),
        nn.Conv2d(384, 256, kernel_size=3, padding=1), nn.ReLU(inplace=True),
        nn.Conv2d(256, 256, kernel_size=3, padding=1), nn.ReLU(inplace=True),
        nn.MaxPool2d(kernel_size=3, stride=2),
    )


class AlexNet(nn.Module):
    """torchvision's AlexNet (PyTorch's default initialisation, as torchvision leaves it)."""

    def __init__(self, *, classifier: bool = True, num_classes: int = 1000,
                 dropout: float = 0.5) -> None:
        super().__init__()
        self.features = make_features()
        if classifier:
            self.avgpool = nn.AdaptiveAvgPool2d((6, 6))
            self.classifier = nn.Sequential(
                nn.Dropout(p=dropout), nn.Linear(256 * 6 * 6, 4096), nn.ReLU(inplace=True),
                nn.Dropout(p=dropout), nn.Linear(4096, 4096), nn.ReLU(inplace=True),
                nn.Linear(4096, num_classes))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.features(x)
        if not hasattr(self, "classifier"):
            return x
        return self.classifier(torch.flatten(self.avgpool(x), 1))


def expected_keys(*, classifier: bool = True) -> dict[str, tuple[int, ...]]:
    """Name -> shape of every state-dict entry (built on the 'meta' device)."""
    with torch.device("meta"):
        model = AlexNet(classifier=classifier)
    return {k: tuple(v.shape) for k, v in model.state_dict().items()}
