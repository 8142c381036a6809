"""Command line of ``cgvq-analyze``: parses arguments, prints, sets exit codes."""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from .errors import AnalysisError
from .outliers import METHODS as OUTLIER_METHODS
from .scores import MODELS


def _inputs(p: argparse.ArgumentParser) -> None:
    src = p.add_argument_group("ratings (one of)")
    src.add_argument("--sessions", nargs="+", metavar="DIR|FILE",
                     help="session files (*.sqlite) or folders holding them")
    src.add_argument("--ratings", nargs="+", metavar="CSV", help="tidy ratings CSV file(s)")
    src.add_argument("--sureal", metavar="DATASET",
                     help="SUREAL dataset file (.py parsed, never executed, or .json)")
    p.add_argument("--manifest", metavar="M", help="study manifest (with --sessions/--ratings)")
    p.add_argument("--model", choices=MODELS, default="mle",
                   help="score model: mle (SUREAL MLE, default), p910 (MLE_CO_AP2), mos, bt500")
    p.add_argument("--outliers", choices=OUTLIER_METHODS, default="grubbs",
                   help="rater screening: grubbs (default), bt500, none")
    p.add_argument("--alpha", type=float, default=0.05, help="significance level (0.05)")
    p.add_argument("--seed", type=int, default=0, help="seed of bootstrap and splits (0)")
    p.add_argument("--bootstrap", type=int, default=1000, metavar="N",
                   help="bootstrap resamples (1000)")
    p.add_argument("--splits", type=int, default=1000, metavar="N",
                   help="random split-halves for the human ceiling (1000)")
    p.add_argument("-v", "--verbose", action="store_true", help="log progress details")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="cgvq-analyze",
        description="Ratings to reliability, outlier raters, DMOS, human ceiling and metric "
                    "validation.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    p = sub.add_parser("report", help="full analysis: report.html, figures, tables, dmos.csv")
    _inputs(p)
    p.add_argument("--metric", nargs="+", metavar="SCORES_CSV", help="metric score CSV(s)")
    p.add_argument("--notes", metavar="FILE", help="text shown at the top of the report")
    p.add_argument("--out", required=True, metavar="DIR", help="report folder")
    p = sub.add_parser("dmos", help="DMOS CSV only (with the model's raw quality column)")
    _inputs(p)
    p.add_argument("--out", required=True, metavar="CSV", help="DMOS CSV to write")
    p = sub.add_parser("reliability", help="ICC, inter/intra-rater agreement, outlier raters")
    _inputs(p)
    p.add_argument("--out", metavar="DIR", help="also write the tables as CSV here")
    p = sub.add_parser("compare", help="metrics versus DMOS (correlations, significance)")
    _inputs(p)
    p.add_argument("--metric", nargs="+", required=True, metavar="SCORES_CSV")
    p.add_argument("--out", metavar="DIR", help="also write the tables as CSV here")
    p = sub.add_parser("export", help="dmos.csv, SUREAL dataset JSON, P.910 rating matrix")
    _inputs(p)
    p.add_argument("--out", required=True, metavar="DIR")
    return parser


def _load(args: argparse.Namespace):
    from .inputs import load_ratings
    from .sureal_io import load_sureal

    given = [x for x in (args.sessions, args.ratings, args.sureal) if x]
    if len(given) != 1:
        raise AnalysisError("give the ratings with exactly one of --sessions, --ratings, "
                            "--sureal")
    if args.sureal:
        return load_sureal(args.sureal)
    if not args.manifest:
        raise AnalysisError("--sessions and --ratings need --manifest (the study manifest)")
    return load_ratings(args.manifest, ratings_csv=args.ratings, sessions=args.sessions)


def _run(args: argparse.Namespace) -> int:
    from .metrics import load_metric_scores
    from .pipeline import AnalysisConfig, run_analysis
    from .report import summary_text, write_report, write_tables

    if args.bootstrap < 1 or args.splits < 1:
        raise AnalysisError("--bootstrap and --splits must be at least 1")
    rs = _load(args)
    for prob in rs.problems[:5]:
        print(f"input problem: {prob}", file=sys.stderr)
    if len(rs.problems) > 5:
        print(f"... and {len(rs.problems) - 5} more input problem(s)", file=sys.stderr)
    config = AnalysisConfig(model=args.model, outliers=args.outliers, alpha=args.alpha,
                            seed=args.seed, n_boot=args.bootstrap, n_splits=args.splits)
    if args.command == "dmos":
        from .exports import write_dmos_csv
        from .outliers import screen_raters
        from .scores import fit_scores

        screen = screen_raters(rs, args.outliers, alpha=args.alpha)
        kept = rs.with_raters(screen.kept)
        res = fit_scores(kept, args.model)
        path = write_dmos_csv(kept, res, args.out)
        removed = ", ".join(screen.removed_names) or "none"
        print(f"{kept.n_stimuli} stimuli, {kept.n_raters} raters (removed: {removed}); "
              f"model {res.model_name}; wrote {path}")
        return 0
    if args.command == "export":
        from .exports import write_exports
        from .outliers import screen_raters
        from .scores import fit_scores

        screen = screen_raters(rs, args.outliers, alpha=args.alpha)
        res = fit_scores(rs.with_raters(screen.kept), args.model)
        for kind, path in write_exports(rs, res, args.out).items():
            print(f"{kind}: {path}")
        return 0
    metrics = None
    if getattr(args, "metric", None):
        metrics = load_metric_scores(args.metric)
    notes = None
    if getattr(args, "notes", None):
        try:
            notes = Path(args.notes).read_text(encoding="utf-8")
        except OSError as exc:
            raise AnalysisError(f"cannot read --notes file {args.notes} ({exc.strerror})") \
                from None
    analysis = run_analysis(rs, config, metrics, progress=sys.stderr.isatty())
    print(summary_text(analysis))
    if args.command == "report":
        path = write_report(analysis, args.out, notes=notes)
        print(f"report: {path}")
    elif args.out:
        Path(args.out).mkdir(parents=True, exist_ok=True)
        write_tables(analysis, Path(args.out))
        print(f"tables: {Path(args.out) / 'tables'}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    logging.basicConfig(level=logging.INFO if args.verbose else logging.ERROR,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        return _run(args)
    except AnalysisError as exc:
        print(f"cgvq-analyze: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("cgvq-analyze: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
