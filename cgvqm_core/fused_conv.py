"""Stages of the backbone with each convolution, its bias, the residual and the ReLU as one
cuDNN call.

With batch norm folded into the convolutions (:func:`.features._fuse_batchnorm`), PyTorch
runs every convolution of a stage as three or four kernels: the convolution, a pass over
its whole output to add the bias, the residual sum and the ReLU. Under bf16/fp16 on a GPU
those passes over 64-channel activations took about as long as the convolutions
themselves (the H200 profile in ``docs/performance.md``). cuDNN's fused operation
(``torch.cudnn_convolution_relu`` and ``torch.cudnn_convolution_add_relu``) adds the bias and
the residual to the fp32 accumulator and applies the ReLU before the one write of the
output, so the same stage costs one pass per convolution. It is also a little more exact:
the bias and the residual are added before, not after, rounding to bf16/fp16.

Only the R3D and MC3 shapes are fused (a plain stem, blocks of plain convolutions); any other
module runs as it is. :data:`REFERENCE` computes the same function with ordinary operators,
which is how the stage walk is tested where there is no cuDNN.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from .backbone import BasicBlock

ConvRelu = Callable[[torch.Tensor, nn.Conv3d], torch.Tensor]
ConvAddRelu = Callable[[torch.Tensor, nn.Conv3d, torch.Tensor], torch.Tensor]


@dataclass(frozen=True)
class FusedOps:
    """relu(conv(x) + bias) and relu(conv(x) + bias + z), by one implementation."""

    name: str
    conv_relu: ConvRelu
    conv_add_relu: ConvAddRelu


def _cudnn_relu(x: torch.Tensor, conv: nn.Conv3d) -> torch.Tensor:
    return torch.cudnn_convolution_relu(x, conv.weight, conv.bias, conv.stride, conv.padding,
                                        conv.dilation, conv.groups)


def _cudnn_add_relu(x: torch.Tensor, conv: nn.Conv3d, z: torch.Tensor) -> torch.Tensor:
    return torch.cudnn_convolution_add_relu(x, conv.weight, z, 1.0, conv.bias, conv.stride,
                                            conv.padding, conv.dilation, conv.groups)


def _ref_relu(x: torch.Tensor, conv: nn.Conv3d) -> torch.Tensor:
    return F.relu_(conv(x))


def _ref_add_relu(x: torch.Tensor, conv: nn.Conv3d, z: torch.Tensor) -> torch.Tensor:
    return F.relu_(conv(x).add_(z))


CUDNN = FusedOps("cudnn", _cudnn_relu, _cudnn_add_relu)
REFERENCE = FusedOps("reference", _ref_relu, _ref_add_relu)


def _plain_conv(m: nn.Module) -> bool:
    """A convolution cuDNN can fuse: an nn.Conv3d with a bias (batch norm folded in) and
    numeric padding."""
    return (type(m).forward is nn.Conv3d.forward and isinstance(m, nn.Conv3d)
            and m.bias is not None and not isinstance(m.padding, str)
            and m.padding_mode == "zeros")


def _conv_relu_seq(m: nn.Module) -> nn.Conv3d | None:
    """The convolution of a (conv, folded batch norm, ReLU) sequence, else None."""
    if not isinstance(m, nn.Sequential):
        return None
    kids = list(m.children())
    if len(kids) != 3 or not _plain_conv(kids[0]) or not isinstance(kids[1], nn.Identity) \
            or not isinstance(kids[2], nn.ReLU):
        return None
    return kids[0]


def _conv_seq(m: nn.Module) -> nn.Conv3d | None:
    """The convolution of a (conv, folded batch norm) sequence, else None."""
    if not isinstance(m, nn.Sequential):
        return None
    kids = list(m.children())
    if len(kids) != 2 or not _plain_conv(kids[0]) or not isinstance(kids[1], nn.Identity):
        return None
    return kids[0]


def fusable(stage: nn.Module) -> bool:
    """Whether :func:`fused_stage` fuses ``stage`` (a stem, or a layer of basic blocks)."""
    if _conv_relu_seq(stage) is not None:
        return True
    if not isinstance(stage, nn.Sequential) or not len(stage):
        return False
    return all(isinstance(b, BasicBlock) and _conv_relu_seq(b.conv1) is not None
               and _conv_seq(b.conv2) is not None
               and (b.downsample is None or _conv_seq(b.downsample) is not None)
               for b in stage)


def fused_stage(stage: nn.Module, x: torch.Tensor, ops: FusedOps = CUDNN) -> torch.Tensor:
    """``stage(x)`` with every convolution fused with its bias, residual and ReLU
    (``stage`` must be :func:`fusable`; its batch norms folded)."""
    conv = _conv_relu_seq(stage)
    if conv is not None:
        return ops.conv_relu(x, conv)
    for block in stage:
        skip = x if block.downsample is None else block.downsample(x)
        mid = ops.conv_relu(x, _conv_relu_seq(block.conv1))
        x = ops.conv_add_relu(mid, _conv_seq(block.conv2), skip)
        del mid, skip
    return x
