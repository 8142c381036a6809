"""The options every scoring command of ``cgvqm`` shares: their arguments, the checks that
refuse bad values before any work, and the :class:`~cgvqm_core.metrics.MetricOptions` they
become. An option that none of the metrics asked for reads is refused (see
``MetricSpec.reads``), not silently ignored."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from .errors import CGVQMError


def add_metric_options(p: argparse.ArgumentParser, *, multi_variant: bool = False) -> None:
    if multi_variant:
        p.add_argument("--metrics", metavar="LIST",
                       help="comma-separated registry names (`cgvqm metrics` lists them; "
                            "'all' = every available one; default cgvqm-2)")
        p.add_argument("--variant", action="append", choices=("cgvqm-2", "cgvqm-5"),
                       help="same as --metrics for the CGVQM variants (repeatable)")
    else:
        p.add_argument("--metric", metavar="NAME",
                       help="registry name (`cgvqm metrics`; default cgvqm-2)")
        p.add_argument("--variant", choices=("cgvqm-2", "cgvqm-5"),
                       help="CGVQM-2 (stem + layer1, faster) or CGVQM-5 (all layers); "
                            "same as --metric")
    p.add_argument("--display", default="standard_4k",
                   help="viewing condition for FLIP's pixels per degree and ColorVideoVDP's "
                        "display model (default standard_4k: 30-inch 4K at 0.75 m)")
    p.add_argument("--ppd", type=float, help="pixels per visual degree (overrides --display's "
                                              "geometry for FLIP and ColorVideoVDP)")
    p.add_argument("--weights", metavar="PATH",
                   help="omega/alpha file (upstream pickle or cgvqm-weights JSON) instead of "
                        "the variant's published weights; 'uniform' for a smoke test")
    p.add_argument("--backbone", metavar="PATH",
                   help="R3D-18 state dict file (default: $CGVQM_BACKBONE, then the torch hub "
                        "cache, then a download)")
    p.add_argument("--random-backbone", metavar="SEED", type=int,
                   help="use a seeded RANDOM backbone (testing only; every output says so)")
    p.add_argument("--learned-weights", action="append", metavar="PART=PATH|DIR",
                   help="local weights of lpips/lpips-alex/dists/pieapp: PART is vgg16, "
                        "alexnet, lpips, lpips-alex, dists or pieapp; or a folder holding "
                        "the files under their published names (repeatable; never downloaded)")
    p.add_argument("--learned-sha256", action="append", metavar="PART=HEX",
                   help="sha256 a learned-metric weights file must have (repeatable)")
    p.add_argument("--device", default="cpu", help="cpu or cuda (default cpu)")
    p.add_argument("--precision", choices=("auto", "fp32", "tf32", "bf16", "fp16"),
                   default="auto",
                   help="auto (default): what upstream computes as its users run it: fp32 on "
                        "a CPU (bit-identical), tf32 on CUDA (PyTorch's defaults); fp32: "
                        "strict, equal to the CPU also on CUDA; bf16 (CPUs with AMX or "
                        "AVX512-BF16, refused on others with the reason; GPUs) or fp16 "
                        "(GPUs): faster, scores drift slightly (see docs/performance.md)")
    p.add_argument("--fast-stem", action="store_true",
                   help="with --precision fp16 on CUDA: run the stem in TF32 rather than true "
                        "fp32: about 1.5x faster, but q moves further from fp32 (up to 0.03 "
                        "on the demo, 0.07-0.14 far below q = 0; docs/performance.md)")
    p.add_argument("--patch-scale", type=int, default=4,
                   help="patch grid: H/s x W/s pixel patches (default 4, as upstream)")
    p.add_argument("--seamless", action="store_true",
                   help="patches with a halo so features do not depend on the patch grid "
                        "(NOT upstream-identical; no error maps)")
    p.add_argument("--batch-size", type=int,
                   help="videos per network pass (reference + tests; default on a CPU: "
                        "2 for patches up to 16x128x128 or in bf16, else 1; on CUDA as many "
                        "as fit 16 patches of 30x128x128, several patch positions per pass)")
    p.add_argument("--threads", type=int,
                   help="CPU threads for PyTorch (default: PyTorch's choice)")
    p.add_argument("--allow-resample", action="store_true",
                   help="accept a test video whose fps differs from the reference's")
    p.add_argument("--strict", action="store_true",
                   help="refuse (exit 2) a test video whose frame count differs from its "
                        "reference's. Without it such a test is resampled in time to the "
                        "reference's frame count as upstream does (nearest neighbour: frames "
                        "are repeated or dropped, never interpolated) with a warning saying "
                        "how many frames were invented or dropped")
    p.add_argument("--allow-convert", action="store_true",
                   help="convert 10-bit or alpha input to 8-bit RGB (with a warning) "
                        "instead of refusing it")


def on_conversion(args: argparse.Namespace) -> str:
    return "warn" if args.allow_convert else "error"


def _at_least_one(option: str, value: int | None, what: str) -> None:
    if value is not None and value < 1:
        raise CGVQMError(f"{option} must be at least 1 ({what}), got {value}")


def check_options(args: argparse.Namespace) -> None:
    """Refuse counts, seeds and rates out of range before any work. argparse takes any int
    or float, and downstream nothing would fail: a batch size of 0 is clamped to 1, an
    infinite fps gives clips of 30 frames, a negative seed is another seed's network."""
    from .hub import check_seed
    from .stream import check_rate

    _at_least_one("--batch-size", args.batch_size, "videos per network pass")
    _at_least_one("--patch-scale", args.patch_scale, "the patch grid divides H and W by it")
    _at_least_one("--threads", args.threads, "CPU threads for PyTorch")
    _at_least_one("--group-size", getattr(args, "group_size", None),
                  "test videos scored together")
    if args.random_backbone is not None:
        check_seed(args.random_backbone, "--random-backbone SEED")
    if getattr(args, "device", None):
        from .devices import torch_device

        torch_device(args.device)
    check_rate(getattr(args, "fps", None), "--fps")
    png = getattr(args, "emap_png", None)
    if png and Path(png).exists() and not Path(png).is_dir():
        raise CGVQMError(f"--emap-png {png}: is a file; give a folder for the error-map PNGs")
    if getattr(args, "fast_stem", False) and not (
            args.precision == "fp16" and str(args.device).startswith("cuda")):
        raise CGVQMError("--fast-stem applies to --precision fp16 on --device cuda only "
                         "(TF32 is a GPU mode; bf16 keeps its stem exact)")


def set_threads(args: argparse.Namespace) -> None:
    if args.threads is not None:
        import torch

        _at_least_one("--threads", args.threads, "CPU threads for PyTorch")
        torch.set_num_threads(args.threads)


def metric_options(args: argparse.Namespace, pools: list[str]) -> Any:
    from .metrics import MetricOptions, ViewingCondition

    return MetricOptions(
        device=args.device, viewing=ViewingCondition(args.display, args.ppd),
        weights=args.weights, backbone=args.backbone, random_backbone=args.random_backbone,
        precision=args.precision, patch_scale=args.patch_scale, batch_size=args.batch_size,
        seamless=args.seamless, fast_stem=args.fast_stem, pools=tuple(pools),
        **_learned(args))


def _set_options(args: argparse.Namespace) -> list[tuple[str, str]]:
    """(flag, MetricOptions field) for each metric option this run sets to other than its
    default: what some metric asked for must read."""
    from .metrics.viewing import DEFAULT_DISPLAY

    pool = args.pool if isinstance(args.pool, list) else [args.pool]
    given = {
        "--display": ("viewing", str(args.display).strip().lower() != DEFAULT_DISPLAY),
        "--ppd": ("viewing", args.ppd is not None),
        "--weights": ("weights", args.weights is not None),
        "--backbone": ("backbone", args.backbone is not None),
        "--random-backbone": ("random_backbone", args.random_backbone is not None),
        "--precision": ("precision", args.precision != "auto"),
        "--fast-stem": ("fast_stem", args.fast_stem),
        "--patch-scale": ("patch_scale", args.patch_scale != 4),
        "--seamless": ("seamless", args.seamless),
        "--batch-size": ("batch_size", args.batch_size is not None),
        "--pool": ("pools", any(p not in (None, "max") for p in pool)),
        "--learned-weights": ("learned_weights", bool(args.learned_weights)),
        "--learned-sha256": ("learned_sha256", bool(args.learned_sha256)),
    }
    return [(flag, field) for flag, (field, is_set) in given.items() if is_set]


def refuse_unread_options(args: argparse.Namespace, names: list[str],
                          options: Any = None) -> None:
    """An option that none of the metrics asked for reads would be silently ignored (for
    example --precision fp16 with psnr, or a learned-weights file with CGVQM): refuse it,
    saying which metrics it is for. With the run's ``options``, a reader that 'all' left
    out because it cannot run here is named with the reason."""
    from .metrics import get_entry, readers
    from .metrics.viewing import DEFAULT_DISPLAY

    _learned(args)  # a malformed PART=PATH or PART=HEX is named as such first
    for flag, field in _set_options(args):
        if readers(field, names):
            continue
        users = readers(field)
        if options is not None:
            for name in users:
                why = get_entry(name).availability_for(options)
                if not why.ok:
                    raise CGVQMError(f"{flag}: {name} would read it but is not available "
                                     f"here: {why.reason}")
        raise CGVQMError(f"{flag} applies to {', '.join(users)}, not to {', '.join(names)}: "
                         f"drop it, or ask for a metric that reads it")
    _refuse_unread_parts(args, names)
    if args.ppd is not None and str(args.display).strip().lower() != DEFAULT_DISPLAY and (
            "cvvdp" not in names):
        raise CGVQMError("--display gives flip only its pixels per degree, which --ppd fixes: "
                         "drop one of them (cvvdp would read both)")


def _refuse_unread_parts(args: argparse.Namespace, names: list[str]) -> None:
    """A weights file or hash for a part none of the asked metrics loads (an AlexNet file
    with lpips, which uses VGG-16, say) would be ignored, even when it does not exist."""
    from .metrics import entries, get_entry

    used = {p for n in names for p in get_entry(n).weight_parts}
    for flag, specs in (("--learned-weights", args.learned_weights or []),
                        ("--learned-sha256", args.learned_sha256 or [])):
        for spec in specs:
            part, eq, _ = spec.partition("=")
            part = part.strip().lower()
            if not eq or part in used or Path(spec).expanduser().is_dir():
                continue
            users = [e.spec.name for e in entries() if part in e.weight_parts]
            raise CGVQMError(f"{flag} {part}=...: {', '.join(names)} "
                             f"{'does' if len(names) == 1 else 'do'} not load {part} weights "
                             f"(used by {', '.join(users)}): drop it, or ask for one of those")


def _learned(args: argparse.Namespace) -> dict[str, Any]:
    """--learned-weights PART=PATH / DIR and --learned-sha256 PART=HEX as MetricOptions."""
    from .metrics.learned.files import PARTS

    files: dict[str, str] = {}
    dirs: list[str] = []
    sha: dict[str, str] = {}
    for spec in args.learned_weights or []:
        part, eq, path = spec.partition("=")
        if eq and part.strip().lower() in PARTS:
            files[part.strip().lower()] = path
        elif Path(spec).expanduser().is_dir():
            dirs.append(spec)
        else:
            raise CGVQMError(f"--learned-weights {spec!r}: give PART=PATH with PART one of "
                             f"{', '.join(PARTS)}, or an existing folder")
    for spec in args.learned_sha256 or []:
        part, eq, value = spec.partition("=")
        if not eq or part.strip().lower() not in PARTS:
            raise CGVQMError(f"--learned-sha256 {spec!r}: give PART=HEX with PART one of "
                             f"{', '.join(PARTS)}")
        value = value.strip().lower()
        if len(value) != 64 or any(ch not in "0123456789abcdef" for ch in value):
            raise CGVQMError(f"--learned-sha256 {spec!r}: the sha256 is 64 hexadecimal digits")
        sha[part.strip().lower()] = value
    return {"learned_weights": files, "learned_dirs": tuple(dirs), "learned_sha256": sha}
