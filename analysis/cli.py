"""Command line of ``cgvq-analyze``: parses arguments, prints, sets exit codes."""

from __future__ import annotations

import argparse
import logging
import shlex
import sys
from pathlib import Path

from stimuli_manifests.cli_runner import OneLineParser, run_command

from .errors import MAX_RESAMPLES, AnalysisError, check_resamples
from .exports import write_dmos_csv, write_exports
from .inputs import load_ratings
from .metrics import load_metric_scores
from .panel import panel_problems
from .pipeline import DEFAULT_MIN_COMPLETENESS, AnalysisConfig, prepare, run_analysis
from .report import summary_text, write_report, write_tables
from .scores import MODELS, fit_scores
from .screening import DEFAULT_METHOD, method_names, methods_help
from .sureal_io import load_sureal

DEFAULT_ALPHA = 0.05
MAX_LINES = 20  # input problems and exclusions printed on stderr before "... and N more"


def _inputs(p: argparse.ArgumentParser) -> None:
    src = p.add_argument_group("ratings (one of)")
    src.add_argument("--sessions", nargs="+", metavar="DIR|FILE|ZIP",
                     help="session files (*.sqlite), folders or zip archives holding them")
    src.add_argument("--ratings", nargs="+", metavar="CSV", help="tidy ratings CSV file(s)")
    src.add_argument("--sureal", metavar="DATASET",
                     help="SUREAL dataset file (.py parsed, never executed, or .json)")
    p.add_argument("--manifest", metavar="M", help="study manifest (with --sessions/--ratings)")
    p.add_argument("--model", choices=MODELS, default="mle",
                   help="score model: mle (SUREAL MLE, default), p910 (MLE_CO_AP2), mos, bt500")
    p.add_argument("--outliers", choices=method_names(), default=DEFAULT_METHOD,
                   help=methods_help())
    p.add_argument("--min-completeness", type=float, default=DEFAULT_MIN_COMPLETENESS,
                   metavar="F", help="leave out raters who answered less than this share of "
                   f"their planned trials ({DEFAULT_MIN_COMPLETENESS}; 0 keeps everyone)")
    p.add_argument("--include-pilots", action="store_true",
                   help="keep sessions paced without vsync (--pilot-no-vsync: pilots) beside "
                        "participants' sessions (default: leave them out; a pilot alone is "
                        "analysed as it is)")
    p.add_argument("--exclude-failed-vision", action="store_true",
                   help="leave out raters who failed a vision check of the study's panel "
                        "(reported like any other exclusion; default: flag them only)")
    p.add_argument("--alpha", type=float, default=DEFAULT_ALPHA,
                   help="significance level of the tests, in (0, 0.5) (0.05)")
    p.add_argument("--seed", type=int, default=0,
                   help="seed of bootstraps and splits, a whole number >= 0 (0)")
    p.add_argument("--bootstrap", type=int, default=1000, metavar="N",
                   help=f"bootstrap resamples, 1 to {MAX_RESAMPLES} (1000)")
    p.add_argument("--splits", type=int, default=1000, metavar="N",
                   help=f"random split-halves for the human ceiling, 1 to {MAX_RESAMPLES} "
                        "(1000)")
    p.add_argument("-v", "--verbose", action="store_true", help="log progress details")


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
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
    p = sub.add_parser("pilot", help="a pilot's ratings by distortion level, one rater or "
                                     "more: levels numbered the wrong way round, levels rated "
                                     "alike, a level nobody saw, the use of the scale")
    src = p.add_argument_group("ratings (one of)")
    src.add_argument("--sessions", nargs="+", metavar="DIR|FILE|ZIP",
                     help="the pilots' session files, folders or zips (pilots included)")
    src.add_argument("--ratings", nargs="+", metavar="CSV", help="tidy ratings CSV file(s)")
    p.add_argument("--manifest", required=True, metavar="M", help="study manifest")
    p.add_argument("--out", metavar="CSV", help="also write the per-stimulus table here")
    p.add_argument("-v", "--verbose", action="store_true", help="log progress details")
    return parser


def _load(args: argparse.Namespace):
    given = [x for x in (args.sessions, args.ratings, args.sureal) if x]
    if len(given) != 1:
        raise AnalysisError("give the ratings with exactly one of --sessions, --ratings, "
                            "--sureal")
    if args.sureal:
        return load_sureal(args.sureal)
    if not args.manifest:
        raise AnalysisError("--sessions and --ratings need --manifest (the study manifest)")
    return load_ratings(args.manifest, ratings_csv=args.ratings, sessions=args.sessions,
                        include_pilots=args.include_pilots)


def _refuse_unread(args: argparse.Namespace) -> None:
    """Options this command would not read are refused, not ignored: --manifest with a
    SUREAL dataset (it carries its stimuli), --alpha where no test uses it (the screening
    would look stricter or looser than it was), --exclude-failed-vision with inputs that
    never carry vision checks. (Resampling counts stay shared by every subcommand, so one
    set of options serves them all.)"""
    from .screening import rules

    if args.sureal and args.manifest:
        raise AnalysisError("--manifest is read with --sessions/--ratings; a SUREAL dataset "
                            "carries its own stimuli: drop --manifest")
    metric_tests = args.command == "compare" or bool(getattr(args, "metric", None))
    if args.alpha != DEFAULT_ALPHA and not (rules()[args.outliers].uses_alpha or metric_tests):
        uses = [r.name for r in rules().values() if r.uses_alpha]
        raise AnalysisError(f"--alpha is the significance level of --outliers "
                            f"{'/'.join(uses)} and of the metric comparisons (--metric); "
                            f"{args.command} with --outliers {args.outliers} runs no test "
                            "that uses it: drop it")
    if args.include_pilots and not args.sessions:
        raise AnalysisError("--include-pilots needs session files (--sessions): ratings CSVs "
                            "and SUREAL datasets do not say how a rating was shown")
    if args.exclude_failed_vision and not args.sessions:
        raise AnalysisError("--exclude-failed-vision needs session files (--sessions): "
                            "ratings CSVs and SUREAL datasets carry no vision checks")


def _refuse_no_vision_checks(args: argparse.Namespace, rs) -> None:
    """--exclude-failed-vision on ratings in which nobody took a vision check."""
    if args.exclude_failed_vision and (rs.panel is None or not any(
            rs.panel.screenings.values())):
        raise AnalysisError("--exclude-failed-vision: no participant took a vision check in "
                            "these sessions (the study's panel screens no vision); drop it")


def _check_out(args: argparse.Namespace) -> None:
    """``--out`` must not be a file where a folder is written, nor a folder for a CSV."""
    out = getattr(args, "out", None)
    if not out:
        return
    path = Path(out)
    if args.command == "dmos":
        if path.is_dir():
            raise AnalysisError(f"--out {out} is a folder; give the DMOS CSV file to write")
        if path.exists():
            _refuse_replacing_other_than_dmos(path)
    elif path.exists() and not path.is_dir():
        raise AnalysisError(f"--out {out} is an existing file; give a folder for the "
                            f"{args.command} output")


def _refuse_replacing_other_than_dmos(path: Path) -> None:
    """Only a DMOS CSV written before is replaced: ``--out`` on a session file, the ratings
    CSV or the manifest would destroy an input (and the next analysis would quietly lose a
    rater)."""
    from stimuli_manifests.errors import TableError
    from stimuli_manifests.tables import DMOS, read_table

    try:
        read_table(path, DMOS)
    except (TableError, OSError, ValueError):
        raise AnalysisError(f"--out {path} exists and is not a DMOS CSV ({DMOS.version}); "
                            "choose another --out (only a DMOS CSV written before is "
                            "replaced)") from None


def _say(lines: list[str], what: str) -> None:
    for line in lines[:MAX_LINES]:
        print(f"{what}: {line}", file=sys.stderr)
    if len(lines) > MAX_LINES:
        print(f"... and {len(lines) - MAX_LINES} more {what} line(s)", file=sys.stderr)


def _read_notes(path: str | None) -> str | None:
    """The text of ``--notes`` (read before any work, so a bad file fails fast)."""
    if not path:
        return None
    try:
        return Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise AnalysisError(f"cannot read --notes file {path} ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        byte = exc.object[exc.start]
        raise AnalysisError(f"--notes file {path} is not UTF-8 text (byte 0x{byte:02x} at "
                            f"offset {exc.start}); give a plain-text file saved as UTF-8") \
            from None


def _pilot(args: argparse.Namespace) -> int:
    """``pilot``: the ratings by level, with no panel statistics (one rater is enough)."""
    from .pilot_view import pilot_lines, pilot_view

    if (args.sessions is None) == (args.ratings is None):
        raise AnalysisError("give the ratings with exactly one of --sessions, --ratings")
    if args.out and Path(args.out).is_dir():
        raise AnalysisError(f"--out {args.out} is a folder; give the CSV file to write")
    rs = load_ratings(args.manifest, ratings_csv=args.ratings, sessions=args.sessions,
                      include_pilots=args.sessions is not None)
    _say([str(x) for x in rs.exclusions], "excluded")
    _say([str(p) for p in rs.problems], "input problem")
    if rs.n_raters == 0:
        raise AnalysisError("no ratings to look at in these inputs")
    view = pilot_view(rs)
    raters = f"{rs.n_raters} rater{'s' if rs.n_raters != 1 else ''}"
    print(f"pilot of study {rs.study}: {raters}, {rs.n_ratings} ratings "
          "(hints for the study's design, not results)")
    for line in pilot_lines(view, rs):
        print(f"  {line}")
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        view.stimuli.to_csv(args.out, float_format="%.4g")
        print(f"wrote {args.out}")
    return 0


def _run(args: argparse.Namespace) -> int:
    if args.command == "pilot":
        return _pilot(args)
    check_resamples(args.bootstrap, "--bootstrap")
    check_resamples(args.splits, "--splits")
    notes = _read_notes(getattr(args, "notes", None))
    config = AnalysisConfig(model=args.model, outliers=args.outliers, alpha=args.alpha,
                            seed=args.seed, n_boot=args.bootstrap, n_splits=args.splits,
                            min_completeness=args.min_completeness,
                            exclude_failed_vision=args.exclude_failed_vision).check()
    _refuse_unread(args)
    _check_out(args)
    rs = _load(args)
    _refuse_no_vision_checks(args, rs)
    _say([str(x) for x in rs.exclusions], "excluded")
    _say([str(p) for p in rs.problems], "input problem")
    if args.command in ("dmos", "export"):
        _, screen, kept = prepare(rs, config)
        _say([str(x) for x in kept.exclusions if x not in rs.exclusions], "excluded")
        _say([str(p) for p in kept.problems if p not in rs.problems], "input problem")
        res = fit_scores(kept, args.model, n_boot=config.n_boot, seed=config.seed)
        _say([str(p) for p in res.problems if p not in kept.problems], "input problem")
        if res.fallback:
            print(f"warning: {res.fallback}", file=sys.stderr)
        if args.command == "dmos":
            path = write_dmos_csv(kept, res, args.out)
            from .screening import rules

            rule = rules().get(screen.method)
            removed = (f"not screened: {screen.method} needs at least {rule.min_raters} "
                       "raters" if rule is not None and kept.n_raters + len(
                           screen.removed_names) < rule.min_raters else
                       "screened out: " + (", ".join(screen.removed_names) or "none"))
            print(f"{kept.n_stimuli} stimuli, {kept.n_raters} raters ({removed}); "
                  f"model {res.model_name}; wrote {path}")
            return 0
        for kind, path in write_exports(kept, res, args.out, raw=rs).items():
            print(f"{kind}: {path}")
        return 0
    metrics = None
    if getattr(args, "metric", None):
        metrics = load_metric_scores(args.metric)
        if args.manifest:  # a SUREAL dataset has no videos to compare with
            from .inputs import read_manifest
            from .scored_videos import check_scored_videos

            check_scored_videos(metrics, read_manifest(args.manifest).manifest.stimuli(
                include_hidden_references=True), args.manifest)
    analysis = run_analysis(rs, config, metrics, progress=sys.stderr.isatty())
    _say([str(x) for x in analysis.exclusions if x not in rs.exclusions], "excluded")
    _say([str(p) for p in analysis.screened.problems if p not in rs.problems], "input problem")
    _say([str(p) for p in panel_problems(rs.panel) if p not in rs.problems],
         "input problem")  # questionnaire answers their question refuses, left out
    _say([str(p) for p in analysis.scores.problems
          if p not in rs.problems and p not in analysis.screened.problems], "input problem")
    said = [*rs.problems, *analysis.screened.problems, *panel_problems(rs.panel),
            *analysis.scores.problems]
    # the rest: the metric scores' (partial coverage, no DMOS), reliability's, the ceiling's
    _say([str(p) for p in analysis.problems if p not in said], "input problem")
    if analysis.scores.fallback:
        print(f"warning: {analysis.scores.fallback}", file=sys.stderr)
    print(summary_text(analysis))
    if args.command == "report":
        path = write_report(analysis, args.out, notes=notes, inputs=_provenance(args))
        print(f"report: {path}")
    elif args.out:
        Path(args.out).mkdir(parents=True, exist_ok=True)
        write_tables(analysis, Path(args.out))
        print(f"tables: {Path(args.out) / 'tables'}")
    return 0


def folder_files(folder: Path) -> list[dict[str, str]]:
    """Every file in a sessions folder the analysis could read (session files, zips, the
    pull's listing), by its path inside the folder, with its sha256: a folder's path alone
    cannot tell a reviewer whether they hold the same files."""
    from stimuli_manifests.checksums import sha256_file

    return [{"name": q.relative_to(folder).as_posix(), "sha256": sha256_file(q)}
            for q in sorted(folder.rglob("*"))
            if q.is_file() and q.suffix in (".sqlite", ".zip", ".json")]


def _provenance(args: argparse.Namespace) -> dict[str, object]:
    """The files a report was made from, each with its sha256, and the command line."""
    from stimuli_manifests.checksums import sha256_file

    def files(paths: list[str] | None) -> list[dict[str, object]]:
        return [{"path": str(Path(p).resolve()),
                 **({"sha256": sha256_file(Path(p))} if Path(p).is_file() else {}),
                 **({"files": folder_files(Path(p))} if Path(p).is_dir() else {})}
                for p in paths or []]

    out: dict[str, object] = {"command": shlex.join(["cgvq-analyze", *args.argv])}
    if args.manifest:
        out["manifest"] = files([args.manifest])[0]
    for key in ("sessions", "ratings", "metric"):
        if getattr(args, key, None):
            out[key] = files(getattr(args, key))
    return out


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    if args.command is None:
        parser.print_help()
        return 0
    logging.basicConfig(level=logging.INFO if args.verbose else logging.ERROR,
                        format="%(levelname)s %(name)s: %(message)s")
    return run_command("cgvq-analyze", lambda: _run(args), extra="analysis")


if __name__ == "__main__":
    sys.exit(main())
