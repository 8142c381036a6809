"""The stem's convolution rewritten for cuDNN's fast kernels, each the same function.

The stem (a 3x7x7 convolution of 3-channel video, stride 1x2x2) is the one convolution of
the network that reads few channels, and under fp16 the one kept in fp32: on an H200 it
took about 0.10 s of the 0.23 s a 3 s 1024x1024 pair costs (docs/performance.md). Each
rewrite here is a new stem convolution and the input it takes:

- :mod:`.padding`: zero channels up to a 16-byte voxel;
- :mod:`.split`: fp32's numbers from one TF32 convolution of split operands;
- :mod:`.frames`: one 2D convolution over all frames, the temporal taps as channels;
- :mod:`.phases`: a strided 2D convolution as a stride-1 one over its input's stride phases
  (space-to-depth), for a 2D stem;
- :mod:`.rewrite`: which of them a network runs (:class:`StemRewrite`).

:mod:`.windows` makes their inputs: strided windows of the input, zeros around them.
"""

from .frames import FramesStem, frames_as_channels
from .padding import pad_stem_conv, padded_channels, padded_input
from .phases import PhaseConv2d, phase_weight, phases_as_channels
from .rewrite import StemRewrite
from .split import SPLITS, SplitStem, round_tf32

__all__ = ["SPLITS", "FramesStem", "PhaseConv2d", "SplitStem", "StemRewrite",
           "frames_as_channels", "pad_stem_conv", "padded_channels", "padded_input",
           "phase_weight", "phases_as_channels", "round_tf32"]
