"""``cgvqm calibrate``: the command line of the calibration (parse, print, exit codes).

Hooked into ``cgvqm_core.cli`` with ``register(subparsers)`` and ``run(args)``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from stimuli_manifests import StimuliError
from stimuli_manifests.cli_runner import (
    EXIT_INTERRUPTED,
    EXIT_TERMINATED,
    OneLineParser,
    Terminated,
    one_line,
)

from ..errors import CGVQMError
from ..ray_options import add_ray_arguments, ray_settings
from .arguments import (
    ANCHOR_METHODS,
    DMOS_SCALES,
    OBJECTIVES,
    POOLINGS,
    SELECTIONS,
    DatasetSpec,
)

if TYPE_CHECKING:
    from .pipeline import CalibrationOutcome, FeatureSource


def default_cache() -> Path:
    """$CGVQM_FEATURE_CACHE, else the metric's cache folder + /features."""
    env = os.environ.get("CGVQM_FEATURE_CACHE")
    if env:
        return Path(env).expanduser()
    from ..weights import cache_dir

    return cache_dir() / "features"


#: the fit's options and their defaults (what --features-only would leave unused)
FIT_DEFAULTS: dict[str, Any] = {
    "steps": 100_000, "lr_omega": 1e-6, "lr_alpha": 1.0, "alpha_init": 1000.0,
    "objective": "plcc", "pool": "max", "select": "train", "val_ratio": 0.25, "seed": 0,
    "anchor": "logistic"}
#: the validation's options and their defaults (what --no-validation leaves unused)
VALIDATION_DEFAULTS: dict[str, Any] = {"train_ratio": None, "repeats": 10, "report": None}


def _flag(dest: str) -> str:
    return "--" + dest.replace("_", "-")


def _refuse_unused(args: argparse.Namespace) -> None:
    """Options this run would not read are refused, not ignored: the fit's and the
    validation's with --features-only, the validation's with --no-validation, alpha's with
    a correlation objective (blind to alpha's scale; alpha is refitted by least squares
    after the fit), --val-ratio without --select val."""
    def given(defaults: dict[str, Any]) -> list[str]:
        return [_flag(k) for k, v in defaults.items() if getattr(args, k) != v]

    if args.features_only:
        unused = given(FIT_DEFAULTS) + given(VALIDATION_DEFAULTS) + (
            ["--no-validation"] if args.no_validation else []) + (
            ["--out"] if args.out is not None else [])
        if unused:
            raise CGVQMError(f"--features-only stops once the feature cache is filled: "
                             f"{', '.join(unused)} would do nothing; drop "
                             f"{'it' if len(unused) == 1 else 'them'}")
        return
    if args.out is None:
        raise CGVQMError("--out W: give the weights file to write (.json)")
    if args.no_validation and given(VALIDATION_DEFAULTS):
        raise CGVQMError(f"{given(VALIDATION_DEFAULTS)[0]} describes the validation splits, "
                         "which --no-validation skips: drop one of them")
    alpha = given({"lr_alpha": FIT_DEFAULTS["lr_alpha"],
                   "alpha_init": FIT_DEFAULTS["alpha_init"]})
    if alpha and args.objective != "nmse":
        raise CGVQMError(f"{alpha[0]} has no effect with --objective {args.objective} (the "
                         "correlation ignores alpha's scale, and alpha is refitted by least "
                         "squares after the fit); it applies to --objective nmse")
    if args.val_ratio != FIT_DEFAULTS["val_ratio"] and args.select != "val":
        raise CGVQMError("--val-ratio sets the held-out share of --select val; add --select "
                         "val or drop it")


def register(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``calibrate`` subcommand to the ``cgvqm`` parser."""
    p = subparsers.add_parser(
        "calibrate", help="fit the feature weights (omega, alpha) to human scores",
        description="Fit CGVQM's channel weights to DMOS of one or more studies: features "
                    "are cached once (resumable), the fit is validated on repeated "
                    "scene-disjoint splits, then fitted on all scenes, anchored to the 0..100 "
                    "scale and saved as a cgvqm-weights/1 file for `cgvqm score --weights`.")
    p.add_argument("--dataset", action="append", required=True, metavar="NAME=MANIFEST:DMOS_CSV",
                   help="a study: its manifest and its DMOS CSV (repeatable)")
    p.add_argument("--variant", choices=("cgvqm-2", "cgvqm-5"), default="cgvqm-2")
    p.add_argument("--out", metavar="W",
                   help="weights file to write (.json; not with --features-only)")
    p.add_argument("--cache", metavar="DIR",
                   help="feature cache folder (default $CGVQM_FEATURE_CACHE, else features/ "
                        "in the metric's cache: $CGVQM_CACHE or ~/.cache/cgvqm); reruns "
                        "reuse it")
    p.add_argument("--features-only", action="store_true",
                   help="fill the feature cache and stop")
    p.add_argument("--dmos-scale", choices=DMOS_SCALES, default="quality",
                   help="quality: DMOS 100 = like the reference (this toolkit, ITU-T P.910; "
                        "default); impairment: larger = worse (target = 100 - DMOS)")
    p.add_argument("--include-references", action="store_true",
                   help="also fit on hidden references (zero error) when the DMOS CSV has them")
    g = p.add_argument_group("fit")
    g.add_argument("--steps", type=int, default=FIT_DEFAULTS["steps"],
                   help="Adam steps (default 100000)")
    g.add_argument("--lr-omega", type=float, default=FIT_DEFAULTS["lr_omega"],
                   help="default 1e-6 (upstream)")
    g.add_argument("--lr-alpha", type=float, default=FIT_DEFAULTS["lr_alpha"],
                   help="default 1.0 (upstream); with --objective nmse only")
    g.add_argument("--alpha-init", type=float, default=FIT_DEFAULTS["alpha_init"],
                   help="default 1000 (upstream); with --objective nmse only")
    g.add_argument("--objective", choices=OBJECTIVES, default=FIT_DEFAULTS["objective"],
                   help="plcc: sum of 1 - |PLCC| over datasets (upstream, default; blind to "
                        "the sign); plcc-signed: 1 - PLCC(q, DMOS), only the right direction "
                        "counts; nmse: squared error of q against the DMOS over its variance")
    g.add_argument("--pool", choices=POOLINGS, default=FIT_DEFAULTS["pool"],
                   help="patch pooling the weights are fitted for (default max, as upstream)")
    g.add_argument("--select", choices=SELECTIONS, default=FIT_DEFAULTS["select"],
                   help="which step's weights to keep: lowest training loss (default, as "
                        "upstream), lowest loss on held-out validation scenes, or the last")
    g.add_argument("--val-ratio", type=float, default=FIT_DEFAULTS["val_ratio"],
                   help="share of training scenes held out for --select val (default 0.25)")
    g.add_argument("--seed", type=int, default=FIT_DEFAULTS["seed"],
                   help="seed of omega's random start and of the first split (default 0)")
    v = p.add_argument_group("validation")
    v.add_argument("--train-ratio", type=float, action="append", metavar="R",
                   help="share of each dataset's scenes used for training (repeatable; "
                        "default 0.2, the paper's 20:80)")
    v.add_argument("--repeats", type=int, default=VALIDATION_DEFAULTS["repeats"],
                   help="distinct scene splits per train ratio, drawn by seeds SEED, SEED+1, "
                        "... (a seed repeating a split is skipped); all of them when there "
                        "are no more (default 10)")
    v.add_argument("--no-validation", action="store_true",
                   help="skip the repeated splits (only the final fit)")
    v.add_argument("--report", metavar="PATH",
                   help="write the validation per split as CSV (PATH) and its summary "
                        "(PATH with .summary.csv)")
    p.add_argument("--anchor", choices=(*ANCHOR_METHODS, "none"),
                   default=FIT_DEFAULTS["anchor"],
                   help="monotone map of q onto the 0..100 scale (default logistic)")
    f = p.add_argument_group("features (the metric's network)")
    f.add_argument("--backbone", metavar="PATH",
                   help="R3D-18 state dict file (default: $CGVQM_BACKBONE, the torch hub cache, "
                        "a download)")
    f.add_argument("--random-backbone", metavar="SEED", type=int,
                   help="a seeded RANDOM backbone (testing only; the weights file says so)")
    f.add_argument("--device", default="cpu", help="cpu or cuda (default cpu)")
    f.add_argument("--precision", choices=("fp32", "bf16", "fp16"), default="fp32")
    f.add_argument("--patch-scale", type=int, default=4, help="default 4 (upstream)")
    f.add_argument("--batch-size", type=int,
                   help="videos per network pass (default 2 on a CPU; on CUDA "
                        "as many as fit 16 patches of 30x128x128)")
    f.add_argument("--allow-resample", action="store_true",
                   help="accept test videos whose fps differs from the reference's")
    f.add_argument("--allow-convert", action="store_true",
                   help="convert 10-bit or alpha input to 8-bit RGB instead of refusing it")
    add_ray_arguments(p)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    return p


def _check(args: argparse.Namespace) -> None:
    ratios = args.train_ratio or [0.2]
    for r in ratios:
        if not 0.0 < r < 1.0:
            raise CGVQMError(f"--train-ratio {r}: must be between 0 and 1 (exclusive)")
    if args.steps < 1:
        raise CGVQMError("--steps must be at least 1")
    if args.repeats < 1:
        raise CGVQMError("--repeats must be at least 1")
    if not 0.0 < args.val_ratio < 1.0:
        raise CGVQMError("--val-ratio must be between 0 and 1 (exclusive)")
    if args.seed < 0:
        raise CGVQMError(f"--seed {args.seed}: must be 0 or more")
    for name, value, low in (("--lr-omega", args.lr_omega, "positive"),
                             ("--lr-alpha", args.lr_alpha, "0 or more"),
                             ("--alpha-init", args.alpha_init, "positive")):
        ok = math.isfinite(value) and (value >= 0 if low == "0 or more" else value > 0)
        if not ok:
            raise CGVQMError(f"{name} {value:g}: must be a finite number, {low}")
    _refuse_unused(args)
    if args.out is None:
        return  # --features-only
    out = Path(args.out)
    if out.suffix.lower() != ".json":
        raise CGVQMError(f"--out {out}: the weights file is JSON; give a name ending in .json")
    if out.is_dir():
        raise CGVQMError(f"--out {out}: is a folder; give a file name ending in .json")
    if not out.parent.is_dir():
        raise CGVQMError(f"--out {out}: folder {out.parent} does not exist")
    if out.exists() and not _is_weights_file(out):
        raise CGVQMError(f"--out {out} exists and is not a CGVQM weights file (a dataset's "
                         "manifest, say); choose another --out (only weights written before "
                         "are replaced)")
    if args.report is not None:
        _check_report(Path(args.report), out, args.dataset)


def _is_weights_file(path: Path) -> bool:
    """Whether ``path`` holds a weights JSON this command (or the published set) wrote."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(data, dict) and str(data.get("format", "")).startswith("cgvqm-weights/")


def _same_file(a: Path, b: Path) -> bool:
    """Whether two paths name one file (existing or not)."""
    try:
        if a.exists() and b.exists():
            return a.samefile(b)
    except OSError:
        pass
    return a.resolve() == b.resolve()


def _check_report(report: Path, out: Path, datasets: list[str]) -> None:
    """--report is written after the fit: refuse before it a path that cannot be written or
    that would overwrite the weights file or a study's manifest or DMOS CSV."""
    summary = report.with_suffix(".summary.csv")
    if report.is_dir():
        raise CGVQMError(f"--report {report}: is a folder; give a file name (.csv)")
    if not report.parent.is_dir():
        raise CGVQMError(f"--report {report}: folder {report.parent} does not exist")
    inputs = [("--out", out)]
    for text in datasets:
        spec = DatasetSpec.parse(text)
        inputs += [(f"--dataset {spec.name}", spec.manifest),
                   (f"--dataset {spec.name}", spec.dmos_csv)]
    for written, label in ((report, "--report"), (summary, "its summary")):
        for flag, path in inputs:
            if _same_file(written, path):
                raise CGVQMError(f"--report {report}: {label} ({written}) would overwrite "
                                 f"the file of {flag}; choose another --report")


def run(args: argparse.Namespace) -> int:
    """Execute ``cgvqm calibrate``; returns the exit code (2 for user errors)."""
    try:
        return _run(args)
    except (CGVQMError, StimuliError) as exc:
        print(f"cgvqm: error: {one_line(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        how = "stopped by SIGTERM" if isinstance(exc, Terminated) else "interrupted"
        print(f"cgvqm: {how}; features computed so far are cached, rerun to continue",
              file=sys.stderr)
        return EXIT_TERMINATED if isinstance(exc, Terminated) else EXIT_INTERRUPTED


def _run(args: argparse.Namespace) -> int:
    from .data import load_datasets
    from .fitting import FitConfig
    from .pipeline import build_data, calibrate, metric_features

    _check(args)
    cluster = ray_settings(args, args.device)  # no Ray: says so before any work
    specs = [DatasetSpec.parse(t) for t in args.dataset]
    show = not args.quiet
    # the studies first: their mistakes show before the network is built
    items = load_datasets(specs, dmos_scale=args.dmos_scale,
                          include_references=args.include_references)
    if not args.features_only and not args.no_validation:
        from .splits import training_scenes

        counts = items.groupby("dataset")["scene"].nunique().to_dict()
        for note in training_scenes(counts, args.train_ratio or [0.2]):
            print(f"note: {note}")
    feature_args = {"variant": args.variant, "backbone": args.backbone,
                    "random_backbone": args.random_backbone, "device": args.device,
                    "precision": args.precision, "patch_scale": args.patch_scale,
                    "batch_size": args.batch_size, "allow_resample": args.allow_resample,
                    "on_conversion": "warn" if args.allow_convert else "error"}
    cache_root = Path(args.cache) if args.cache else default_cache()
    if cluster is None:
        source = metric_features(**feature_args)
        _warn_random(source)
        data = build_data(items, source, cache_root, show_progress=show)
    else:
        from ..distributed import connected
        from .ray_features import feature_source

        if args.backbone:  # the workers' working folder is not this one
            feature_args["backbone"] = os.path.abspath(args.backbone)
        with connected(cluster):
            source = feature_source(feature_args, cluster)
            _warn_random(source)
            data = build_data(items, source, cache_root, show_progress=show)
    n_scenes = data.items.groupby("dataset")["scene"].nunique()
    print(f"{len(data.items)} videos, {data.M.shape[1]} patches at most, "
          f"{data.M.shape[2]} channels; scenes per dataset: "
          + ", ".join(f"{k} {v}" for k, v in n_scenes.items()))
    print(f"feature cache: {cache_root}")
    if args.features_only:
        return 0
    config = FitConfig(steps=args.steps, lr_omega=args.lr_omega, lr_alpha=args.lr_alpha,
                       alpha_init=args.alpha_init, objective=args.objective,
                       pooling=args.pool, select=args.select, seed=args.seed,
                       show_progress=show)
    outcome = calibrate(
        data, args.variant, config, train_ratios=args.train_ratio or [0.2],
        repeats=args.repeats, seed=args.seed, val_ratio=args.val_ratio, anchor=args.anchor,
        validation=not args.no_validation, datasets=specs, dmos_scale=args.dmos_scale,
        feature_settings=source.settings, backbone=source.backbone, out=args.out)
    _print_outcome(outcome, args)
    return 0


def _warn_random(source: FeatureSource) -> None:
    if source.backbone.get("random_seed") is not None:
        print(f"cgvqm: warning: RANDOM backbone (seed {source.backbone['random_seed']}): the "
              "fitted weights are for testing only, and the weights file says so",
              file=sys.stderr)


def _num(x: float | None) -> str:
    """A correlation to 3 decimals, or "undefined" (None: constant scores or too few)."""
    return "undefined" if x is None else f"{x:.3f}"


def _print_outcome(outcome: CalibrationOutcome, args: argparse.Namespace) -> None:
    from .validation import format_summary

    prov = outcome.weights.provenance
    if outcome.validation is not None:
        print()
        counts = ", ".join(f"{c.train_ratio:g}: {len(c.splits)}"
                           + (" (all there are)" if c.enumerated else "")
                           for c in outcome.validation.splits)
        print(f"validation: distinct scene-disjoint splits per train ratio ({counts}), "
              "mean and 95% interval of the mean over them")
        print(format_summary(outcome.validation.summary))
        for note in outcome.validation.notes:
            print(f"note: {note}")
        if args.report:
            rep = Path(args.report)
            outcome.validation.per_split.to_csv(rep, index=False)
            outcome.validation.summary.to_csv(rep.with_suffix(".summary.csv"), index=False)
            print(f"wrote {rep} and {rep.with_suffix('.summary.csv')}")
    ff = prov["final_fit"]
    print()
    print(f"final fit on {ff['scenes']}: {ff['videos']} videos; {prov['selection']}: step "
          f"{ff['best_step']}; alpha refitted to {outcome.weights.alpha:.6g}")
    for d, c in ff["correlations_on_fitted_videos"].items():
        extra = f", RMSE after anchoring {c['rmse_anchored']:.2f}" if "rmse_anchored" in c else ""
        print(f"  {d}: on its own fitted videos (optimistic) PLCC {_num(c['plcc'])}, "
              f"SRCC {_num(c['srcc'])}, KRCC {_num(c['krcc'])}{extra}")
    if prov.get("warning"):
        print(f"warning: {prov['warning']}")
    for warning in outcome.warnings:
        print(f"warning: {warning}")
    print(f"wrote {outcome.path} (use: cgvqm score --weights {outcome.path} ...)")
    if args.report is None and outcome.validation is not None:
        print("(add --report PATH for the per-split table)")


def main(argv: list[str] | None = None) -> int:
    """Stand-alone entry (``python -m cgvqm_core.calibration.cli``) until hooked into cgvqm."""
    parser = OneLineParser(prog="cgvqm")
    sub = parser.add_subparsers(dest="command", required=True)
    register(sub)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
