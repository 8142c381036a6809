"""The VideoResNet family (R3D-18, MC3-18, R(2+1)D-18) in plain PyTorch.

Module and parameter names equal torchvision's, so torchvision checkpoints load with
``load_state_dict(strict=True)`` without depending on torchvision. ``depth`` builds only the
first residual stages (CGVQM-2 needs stem and layer1 only); :meth:`VideoResNet.levels` yields
the activations CGVQM compares, one level at a time, so no caller holds them all at once.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Literal

import torch
from torch import nn

ArchName = Literal["r3d_18", "mc3_18", "r2plus1d_18"]
ARCHS: tuple[str, ...] = ("r3d_18", "mc3_18", "r2plus1d_18")
WIDTHS = (64, 128, 256, 512)
STRIDES = (1, 2, 2, 2)
#: channels of each CGVQM level: the input, the stem, layer1..layer4
LEVEL_CHANNELS = (3, 64, 64, 128, 256, 512)


class Conv3DSimple(nn.Conv3d):
    """Full 3x3x3 convolution (R3D)."""

    def __init__(self, in_planes: int, out_planes: int, midplanes: int | None = None,
                 stride: int = 1, padding: int = 1) -> None:
        super().__init__(in_planes, out_planes, kernel_size=(3, 3, 3), stride=stride,
                         padding=padding, bias=False)

    @staticmethod
    def get_downsample_stride(stride: int) -> tuple[int, int, int]:
        return stride, stride, stride


class Conv3DNoTemporal(nn.Conv3d):
    """1x3x3 convolution: spatial only (the upper stages of MC3)."""

    def __init__(self, in_planes: int, out_planes: int, midplanes: int | None = None,
                 stride: int = 1, padding: int = 1) -> None:
        super().__init__(in_planes, out_planes, kernel_size=(1, 3, 3), stride=(1, stride, stride),
                         padding=(0, padding, padding), bias=False)

    @staticmethod
    def get_downsample_stride(stride: int) -> tuple[int, int, int]:
        return 1, stride, stride


class Conv2Plus1D(nn.Sequential):
    """A 1x3x3 spatial convolution then a 3x1x1 temporal one (R(2+1)D)."""

    def __init__(self, in_planes: int, out_planes: int, midplanes: int, stride: int = 1,
                 padding: int = 1) -> None:
        super().__init__(
            nn.Conv3d(in_planes, midplanes, kernel_size=(1, 3, 3), stride=(1, stride, stride),
                      padding=(0, padding, padding), bias=False),
            nn.BatchNorm3d(midplanes),
            nn.ReLU(inplace=True),
            nn.Conv3d(midplanes, out_planes, kernel_size=(3, 1, 1), stride=(stride, 1, 1),
                      padding=(padding, 0, 0), bias=False),
        )

    @staticmethod
    def get_downsample_stride(stride: int) -> tuple[int, int, int]:
        return stride, stride, stride


ConvBuilder = type[Conv3DSimple] | type[Conv3DNoTemporal] | type[Conv2Plus1D]


class BasicBlock(nn.Module):
    """Two convolutions with batch norm and a residual connection."""

    expansion = 1

    def __init__(self, inplanes: int, planes: int, conv_builder: ConvBuilder, stride: int = 1,
                 downsample: nn.Module | None = None) -> None:
        super().__init__()
        midplanes = (inplanes * planes * 3 * 3 * 3) // (inplanes * 3 * 3 + 3 * planes)
        self.conv1 = nn.Sequential(conv_builder(inplanes, planes, midplanes, stride),
                                   nn.BatchNorm3d(planes), nn.ReLU(inplace=True))
        self.conv2 = nn.Sequential(conv_builder(planes, planes, midplanes), nn.BatchNorm3d(planes))
        self.relu = nn.ReLU(inplace=True)
        self.downsample = downsample
        self.stride = stride

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        residual = x if self.downsample is None else self.downsample(x)
        out = self.conv2(self.conv1(x))
        out += residual
        return self.relu(out)


class BasicStem(nn.Sequential):
    """3x7x7 convolution, spatial stride 2 (R3D, MC3)."""

    def __init__(self) -> None:
        super().__init__(
            nn.Conv3d(3, 64, kernel_size=(3, 7, 7), stride=(1, 2, 2), padding=(1, 3, 3),
                      bias=False),
            nn.BatchNorm3d(64),
            nn.ReLU(inplace=True),
        )


class R2Plus1dStem(nn.Sequential):
    """1x7x7 then 3x1x1 convolutions (R(2+1)D)."""

    def __init__(self) -> None:
        super().__init__(
            nn.Conv3d(3, 45, kernel_size=(1, 7, 7), stride=(1, 2, 2), padding=(0, 3, 3),
                      bias=False),
            nn.BatchNorm3d(45),
            nn.ReLU(inplace=True),
            nn.Conv3d(45, 64, kernel_size=(3, 1, 1), stride=(1, 1, 1), padding=(1, 0, 0),
                      bias=False),
            nn.BatchNorm3d(64),
            nn.ReLU(inplace=True),
        )


class VideoResNet(nn.Module):
    """torchvision's VideoResNet, optionally truncated after ``depth`` residual stages.

    ``depth=4`` with ``classifier=True`` is the complete network (state dict identical to
    torchvision's). Smaller depths leave out layer(depth+1).. and the classifier, so CGVQM-2
    never allocates or runs layer2..layer4.
    """

    def __init__(self, conv_makers: list[ConvBuilder], stem: Callable[[], nn.Module],
                 depth: int = 4, classifier: bool = True, num_classes: int = 400) -> None:
        super().__init__()
        if not 0 <= depth <= 4:
            raise ValueError(f"depth must be 0..4, got {depth}")
        self.depth = depth
        self.inplanes = 64
        self.stem = stem()
        for i in range(depth):
            setattr(self, f"layer{i + 1}",
                    self._make_layer(conv_makers[i], WIDTHS[i], 2, stride=STRIDES[i]))
        if classifier and depth == 4:
            self.avgpool = nn.AdaptiveAvgPool3d((1, 1, 1))
            self.fc = nn.Linear(512 * BasicBlock.expansion, num_classes)
        self._init_like_torchvision()

    def _make_layer(self, conv_builder: ConvBuilder, planes: int, blocks: int,
                    stride: int = 1) -> nn.Sequential:
        downsample = None
        if stride != 1 or self.inplanes != planes * BasicBlock.expansion:
            downsample = nn.Sequential(
                nn.Conv3d(self.inplanes, planes * BasicBlock.expansion, kernel_size=1,
                          stride=conv_builder.get_downsample_stride(stride), bias=False),
                nn.BatchNorm3d(planes * BasicBlock.expansion),
            )
        layers = [BasicBlock(self.inplanes, planes, conv_builder, stride, downsample)]
        self.inplanes = planes * BasicBlock.expansion
        layers += [BasicBlock(self.inplanes, planes, conv_builder) for _ in range(1, blocks)]
        return nn.Sequential(*layers)

    def _init_like_torchvision(self) -> None:
        for m in self.modules():
            if isinstance(m, nn.Conv3d):
                nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
            elif isinstance(m, nn.BatchNorm3d):
                nn.init.constant_(m.weight, 1)
                nn.init.constant_(m.bias, 0)
            elif isinstance(m, nn.Linear):
                nn.init.normal_(m.weight, 0, 0.01)
                nn.init.constant_(m.bias, 0)

    def stages(self) -> list[nn.Module]:
        """The modules that produce levels 1.. (stem, layer1, ...)."""
        return [self.stem] + [getattr(self, f"layer{i + 1}") for i in range(self.depth)]

    def levels(self, x: torch.Tensor, n_levels: int) -> Iterator[torch.Tensor]:
        """Yield CGVQM's levels for a batch: the input itself, then stem, layer1, ...

        ``n_levels`` counts the input (3 for CGVQM-2, 6 for CGVQM-5).
        """
        stages = self.stages()
        if n_levels - 1 > len(stages):
            raise ValueError(f"{n_levels} levels need depth {n_levels - 2}, model has {self.depth}")
        yield x
        for stage in stages[: n_levels - 1]:
            x = stage(x)
            yield x

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for stage in self.stages():
            x = stage(x)
        if not hasattr(self, "fc"):
            return x
        return self.fc(self.avgpool(x).flatten(1))


_MAKERS: dict[str, tuple[list[ConvBuilder], Callable[[], nn.Module]]] = {
    "r3d_18": ([Conv3DSimple] * 4, BasicStem),
    "mc3_18": ([Conv3DSimple] + [Conv3DNoTemporal] * 3, BasicStem),
    "r2plus1d_18": ([Conv2Plus1D] * 4, R2Plus1dStem),
}


def build_backbone(arch: str = "r3d_18", *, depth: int = 4, classifier: bool = True) -> VideoResNet:
    """A randomly initialised network of the family (as torchvision initialises it)."""
    if arch not in _MAKERS:
        raise ValueError(f"unknown architecture {arch!r}; choose one of {', '.join(ARCHS)}")
    makers, stem = _MAKERS[arch]
    return VideoResNet(makers, stem, depth=depth, classifier=classifier)


def r3d_18(**kw: object) -> VideoResNet:
    """R3D-18: the CGVQM backbone."""
    return build_backbone("r3d_18", **kw)  # type: ignore[arg-type]


def mc3_18(**kw: object) -> VideoResNet:
    """MC3-18: 3D convolutions in the stem and layer1, 2D above."""
    return build_backbone("mc3_18", **kw)  # type: ignore[arg-type]


def r2plus1d_18(**kw: object) -> VideoResNet:
    """R(2+1)D-18: every 3D convolution factorised into spatial and temporal parts."""
    return build_backbone("r2plus1d_18", **kw)  # type: ignore[arg-type]


def expected_keys(arch: str = "r3d_18") -> dict[str, tuple[int, ...]]:
    """Name -> shape of every entry of the complete network's state dict (built on 'meta')."""
    with torch.device("meta"):
        model = build_backbone(arch)
    return {k: tuple(v.shape) for k, v in model.state_dict().items()}
