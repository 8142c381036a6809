"""Which numeric precisions the network may run in on which device, and why.

The default, ``auto``, computes what the authors' code computes as its users run it on that
device: ``fp32`` on a CPU (upstream-identical, bit for bit), ``tf32`` on CUDA (PyTorch's
defaults there: cuDNN convolutions may use the tensor cores' TF32 mode, matrix products stay
in fp32). Strict ``fp32`` on CUDA (TF32 off, equal to the CPU's numbers to 1e-4) is an
explicit choice. The others trade bit-exactness for speed; each changes scores slightly (the
drift measured against fp32 is in docs/performance.md, "Speed, memory, devices"):

- ``bf16``: convolutions in bfloat16 with fp32 accumulation (oneDNN on CPU, cuDNN on CUDA);
  the input normalisation, level 0, the unit normalisation across channels and the
  differences stay in fp32. On CPU it is offered only where the processor does bf16 in
  hardware (AMX-BF16 or AVX512-BF16): elsewhere oneDNN would emulate it, slower than fp32
  and still not exact, so it is refused with the reason (no silent fallback, so a run
  never reports a precision it did not use).
- ``fp16``: as bf16 with float16; CUDA only (CPUs with AVX512-FP16/AMX-FP16 are rare and the
  path is not measured there).
- ``tf32``: CUDA only: fp32 tensors, cuDNN convolutions allowed on the tensor cores' TF32
  mode and matrix products in fp32: exactly PyTorch's defaults, which is how upstream runs
  there. ``fp32`` on CUDA turns TF32 off while it runs, so that it agrees with the CPU.

Detection reads PyTorch's own CPU feature probe (cpuinfo) and falls back to the ``flags`` line
of /proc/cpuinfo.
"""

from __future__ import annotations

import contextlib
import functools
import platform
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import torch

from .errors import CGVQMError
from .stem import SPLITS

PRECISIONS = ("auto", "fp32", "tf32", "bf16", "fp16")
AUTO = {"cpu": "fp32", "cuda": "tf32"}
"""What ``auto`` means per device type: what upstream computes as its users run it there."""
#: what each precision computes the convolutions in
DTYPES = {"fp32": torch.float32, "tf32": torch.float32, "bf16": torch.bfloat16,
          "fp16": torch.float16}
CPUINFO = Path("/proc/cpuinfo")


@dataclass(frozen=True)
class CpuBf16:
    """Whether this CPU does bfloat16 arithmetic in hardware, and how that was found."""

    amx_bf16: bool
    avx512_bf16: bool
    source: str  # "torch-cpuinfo", "/proc/cpuinfo" or "unknown"

    @property
    def supported(self) -> bool:
        return self.amx_bf16 or self.avx512_bf16

    @property
    def isa(self) -> str:
        """The instruction set bf16 convolutions will use ('' when none)."""
        return "amx_bf16" if self.amx_bf16 else ("avx512_bf16" if self.avx512_bf16 else "")

    def reason(self) -> str:
        if self.supported:
            return f"this CPU has {self.isa.upper().replace('_', '-')}"
        if self.source == "unknown":
            return "could not read this CPU's features (no PyTorch probe, no /proc/cpuinfo)"
        return "this CPU has neither AMX-BF16 nor AVX512-BF16 (bf16 would be emulated, slower " \
               "than fp32)"


def _cpuinfo_field(name: str) -> str | None:
    """The first ``name : value`` line of /proc/cpuinfo (None where there is none)."""
    try:
        text = CPUINFO.read_text(encoding="ascii", errors="replace")
    except OSError:
        return None
    for line in text.splitlines():
        key, _, value = line.partition(":")
        if key.strip() == name:
            return value.strip()
    return None


def _flags_from_cpuinfo() -> set[str] | None:
    flags = _cpuinfo_field("flags")
    return None if flags is None else set(flags.split())


def _probe_torch() -> dict[str, object] | None:
    """PyTorch's cpuinfo-based feature dict (a private API: guarded, optional)."""
    probe = getattr(getattr(torch._C, "_cpu", None), "_get_cpu_capability", None)
    if probe is None:
        return None
    try:
        caps = probe()
    except Exception:  # a private API: any failure means "not available"
        return None
    if not isinstance(caps, dict) or "avx512_bf16" not in caps:
        return None
    return caps


@functools.cache
def cpu_bf16() -> CpuBf16:
    """Detect AMX-BF16 / AVX512-BF16 (cached: the CPU does not change while we run)."""
    caps = _probe_torch()
    if caps is not None:
        return CpuBf16(bool(caps.get("amx_bf16")), bool(caps.get("avx512_bf16")),
                       "torch-cpuinfo")
    flags = _flags_from_cpuinfo()
    if flags is not None:
        return CpuBf16("amx_bf16" in flags, "avx512_bf16" in flags, str(CPUINFO))
    return CpuBf16(False, False, "unknown")


@functools.cache
def cpu_name() -> str:
    """The processor's model name, for provenance."""
    caps = _probe_torch()
    name = caps.get("cpu_name") if caps else None
    return str(name or _cpuinfo_field("model name") or platform.machine() or "unknown CPU")


def resolve(precision: str, device: torch.device) -> str:
    """The precision ``precision`` stands for on ``device`` (``auto`` resolved)."""
    if precision not in PRECISIONS:
        raise CGVQMError(f"precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    return AUTO.get(device.type, "fp32") if precision == "auto" else precision


def check(precision: str, device: torch.device) -> dict[str, object]:
    """Refuse a precision the device cannot run well; return what provenance should say
    (``precision`` already resolved, see :func:`resolve`)."""
    if precision not in PRECISIONS or precision == "auto":
        raise CGVQMError(f"precision must be one of {', '.join(PRECISIONS[1:])}, got "
                         f"{precision!r}")
    info: dict[str, object] = {"precision": precision,
                               "compute_dtype": str(DTYPES[precision]).removeprefix("torch."),
                               "bit_exact": precision == "fp32"}
    if device.type == "cpu":
        if precision in ("fp16", "tf32"):
            raise CGVQMError(f"precision {precision} is offered on CUDA only; on CPU use fp32 "
                             "(exact) or bf16 (on CPUs with AMX-BF16 or AVX512-BF16)")
        if precision == "bf16":
            cap = cpu_bf16()
            if not cap.supported:
                raise CGVQMError(f"--precision bf16 refused on CPU: {cap.reason()}; use fp32 "
                                 "(the default) or a GPU (--device cuda)")
            info.update(cpu_isa=cap.isa, detected_by=cap.source)
    elif device.type == "cuda":
        if precision == "bf16" and not torch.cuda.is_bf16_supported():
            raise CGVQMError("--precision bf16 refused: this GPU has no bf16 support; use fp16 "
                             "or fp32")
        info["tf32"] = precision == "tf32"
    elif precision != "fp32":
        raise CGVQMError(f"precision {precision} is not offered on {device.type}; use fp32")
    if precision != "fp32":
        info["accumulate"] = "fp32"
    return info


@contextlib.contextmanager
def tf32_mode(device: torch.device, allow: bool, *, benchmark: bool = False
              ) -> Iterator[None]:
    """On CUDA, for the duration (restored after): cuDNN convolutions may use TF32 when
    ``allow`` (PyTorch's default, as upstream runs), never otherwise; matrix products in
    fp32 either way (also PyTorch's default), whatever the process had set. ``benchmark``
    lets cuDNN time its algorithms once per input shape and keep the fastest (CGVQM's
    shapes repeat patch after patch, so the search pays for itself after a few patches)."""
    if device.type != "cuda":
        yield
        return
    cudnn, matmul = torch.backends.cudnn, torch.backends.cuda.matmul
    saved = cudnn.allow_tf32, matmul.allow_tf32, cudnn.benchmark
    cudnn.allow_tf32, matmul.allow_tf32, cudnn.benchmark = allow, False, benchmark
    try:
        yield
    finally:
        cudnn.allow_tf32, matmul.allow_tf32, cudnn.benchmark = saved


@contextlib.contextmanager
def cudnn_tf32(allow: bool) -> Iterator[None]:
    """cuDNN's TF32 switch alone, for the duration (restored after): how the fp32 stem of a
    bf16/fp16 network runs in TF32 while the rest keeps its own settings."""
    cudnn = torch.backends.cudnn
    saved = cudnn.allow_tf32
    cudnn.allow_tf32 = allow
    try:
        yield
    finally:
        cudnn.allow_tf32 = saved


@dataclass(frozen=True)
class FastPath:
    """How the network runs on CUDA beyond its precision: measured on an H200 (issue #21,
    docs/performance.md), each resolved here when not asked for explicitly."""

    tf32_stem: bool  # fp16's fp32 stem in TF32: x1.47, but q off by up to 0.14 (opt-in)
    fused: bool  # convolution, bias, residual and ReLU in one cuDNN call
    pad_stem: bool  # a 16-byte stem voxel: faster in TF32, slower in true fp32
    split_stem: str | None = None  # fp32's stem from one TF32 convolution (not yet timed)
    stem_2d: bool = False  # the stem as one conv2d over frames (not yet timed)
    stem_s2d: bool = False  # that conv2d over its stride phases (not yet timed)


def fast_path(device: torch.device, dtype: torch.dtype, *, fp32_stem: bool, differences: bool,
              fuse_bn: bool, tf32_stem: bool, fused: bool | None,
              pad_stem: bool | None, split_stem: str | None = None,
              tf32_net: bool = False, stem_2d: bool = False, stem_s2d: bool = False
              ) -> FastPath:
    """The fast path for this device and precision; an explicit choice that cannot apply is
    refused with the reason.

    On CUDA by default: fused stages wherever batch norm is folded and the tests are not
    carried as differences (fp32, fp16); the padded stem where the stem runs in TF32 or in
    16 bits (slower in true fp32). The TF32 stem only when asked for: it makes fp16 1.47x
    faster, but moves q against fp32 by up to 0.032 on the demo and, emulated on a CPU, by
    0.068 (CGVQM-2) and 0.14 (CGVQM-5) on real content far below q = 0, over the 0.05 the
    reduced precisions keep to. Elsewhere none of them.

    ``split_stem`` (:data:`.stem.SPLITS`) computes an fp32 stem (strict fp32's, or
    bf16/fp16's) from one TF32 convolution of split operands, fp32's numbers to about 2^-22;
    only when asked for until its speed is measured on a GPU. It replaces the padded and the
    TF32 stem, and is refused for ``tf32_net`` (the tf32 precision keeps upstream's TF32 stem).
    On a CPU it computes the same numbers, slower (it is how the tests check it).

    ``stem_2d`` runs the stem as one conv2d over all frames (:class:`.stem.FramesStem`),
    in whatever precision the stem has, a split stem's too (its 8 or 12 channels times the
    three temporal taps); only when asked for until it is timed on a GPU. ``stem_s2d`` (a 2D
    stem implied) runs that conv2d as a stride-1 one over its input's stride phases
    (space-to-depth, :class:`.stem.PhaseConv2d`): a 4x4 kernel over four times the channels.
    """
    cuda = device.type == "cuda"
    if tf32_stem and not (cuda and fp32_stem):
        raise CGVQMError("a TF32 stem needs --device cuda and bf16/fp16 with the stem in fp32")
    if fused and not cuda:
        raise CGVQMError("fused convolutions need cuDNN: use --device cuda")
    if fused and not fuse_bn:
        raise CGVQMError("fused convolutions need batch norm folded (fuse_bn)")
    if split_stem is not None:
        if split_stem not in SPLITS:
            raise CGVQMError(f"split stem must be one of {', '.join(SPLITS)}, got "
                             f"{split_stem!r}")
        if tf32_stem:
            raise CGVQMError("a split stem and a TF32 stem exclude each other: pick one")
        if tf32_net or not (fp32_stem or dtype == torch.float32):
            raise CGVQMError("a split stem computes an fp32 stem: use fp32, or bf16/fp16 with "
                             "the stem in fp32")
    asked = (("fused convolutions", fused), ("a padded stem", pad_stem),
             ("a split stem", split_stem is not None), ("a 2D stem", stem_2d or stem_s2d))
    for name, on in asked:
        if on and differences:
            raise CGVQMError(f"{name}: not for tests carried as differences (bf16's "
                             "default); also turn differences off")
    tf32_stem = bool(tf32_stem)
    if fused is None:
        fused = cuda and fuse_bn and not differences
    if split_stem is not None:
        pad_stem = False  # the split input is 16-byte aligned already
    elif pad_stem is None:
        stem_fast = tf32_stem or (dtype != torch.float32 and not fp32_stem)
        pad_stem = cuda and not differences and stem_fast
    return FastPath(bool(tf32_stem), bool(fused), bool(pad_stem), split_stem,
                    bool(stem_2d or stem_s2d), bool(stem_s2d))
