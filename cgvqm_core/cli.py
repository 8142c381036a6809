"""Command line of ``cgvqm``: parses arguments, prints, sets exit codes.

User errors (missing or corrupt video, fps mismatch, a frame-count mismatch under --strict,
10-bit/alpha input without --allow-convert, weights failing their hash check or malformed, no
backbone offline, a count, seed or frame rate out of range) print one line on stderr and exit
with code 2. Options are checked before any network is built or video decoded.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from functools import partial
from pathlib import Path
from typing import Any

from stimuli_manifests.cli_runner import OneLineParser, run_command

from .cli_options import (
    add_metric_options,
    check_options,
    metric_options,
    on_conversion,
    refuse_unread_options,
    set_threads,
)
from .errors import CGVQMError
from .metric import quality_label
from .ray_options import add_ray_arguments, ray_settings
from .stage_clock import StageClock
from .version import __version__

log = logging.getLogger(__name__)


class _Once(argparse.Action):
    """An option that takes one value: given twice, the last one silently won."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: Any, option_string: str | None = None) -> None:
        seen = f"_given_{self.dest}"
        if getattr(namespace, seen, False):
            parser.error(f"{option_string} given twice; score takes one (batch takes "
                         f"{option_string} more than once)")
        setattr(namespace, seen, True)
        setattr(namespace, self.dest, values)


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(prog="cgvqm",
                                     description="Score videos with the CGVQM metric.")
    parser.add_argument("--version", action="version", version=f"cgvqm {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress details")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    me = sub.add_parser("metrics", help="list the metric registry and availability here")
    me.add_argument("--json", action="store_true", help="print one JSON array")

    sc = sub.add_parser("score", help="score one test video against its reference")
    sc.add_argument("--ref", required=True, help="reference video (file, PNG folder or .npy)")
    sc.add_argument("--test", required=True, help="test (distorted) video")
    sc.add_argument("--pool", choices=("max", "mean"), default="max", action=_Once,
                    help="CGVQM patch pooling: max (as calibrated, default) or mean "
                         "(upstream demo); one (batch writes several)")
    sc.add_argument("--fps", type=float, help="frame rate of PNG folders / .npy inputs")
    sc.add_argument("--emap", metavar="OUT", help="write the error-map video (.mp4 or .mkv)")
    sc.add_argument("--emap-png", metavar="DIR", help="also write the error map as PNG frames")
    sc.add_argument("--json", action="store_true", help="print one JSON object")
    sc.add_argument("--timing", action="store_true",
                    help="say where the time went (decode, copy, backbone, pooling, idle; "
                         "on stderr, and under 'timing' with --json)")
    sc.add_argument("--csv", metavar="OUT", help="append the score to a scores CSV")
    sc.add_argument("--id", metavar="STIMULUS",
                    help="with --csv: the test's stimulus id in the study's manifest "
                         "(SRC01_HRC03), which the analysis joins on (default: the file's "
                         "name without extension)")
    sc.add_argument("--reference-id", metavar="REFERENCE",
                    help="with --csv: the reference's id in the manifest (SRC01; default: "
                         "the file's name without extension)")
    add_metric_options(sc)

    ba = sub.add_parser("batch", help="score every stimulus of a manifest into a scores CSV")
    ba.add_argument("--manifest", required=True, help="cgvq-manifest/1 JSON file")
    ba.add_argument("--out", required=True, help="scores CSV (appended to; reruns resume)")
    ba.add_argument("--pool", action="append", choices=("max", "mean"),
                    help="CGVQM pooling(s) to write (repeatable; default max)")
    ba.add_argument("--root", help="override the manifest's video root")
    ba.add_argument("--include-references", action="store_true",
                    help="also score each hidden reference against itself")
    ba.add_argument("--group-size", type=int, default=4,
                    help="test videos scored together against one reference (default 4)")
    add_metric_options(ba, multi_variant=True)
    add_ray_arguments(ba)

    we = sub.add_parser("weights", help="fetch, verify or describe the metric's weights")
    wsub = we.add_subparsers(dest="weights_command", metavar="ACTION")
    fe = wsub.add_parser("fetch", help="download (or copy from local files) into the caches")
    fe.add_argument("--from", dest="source", metavar="DIR",
                    help="folder holding cgvqm-2.pickle / cgvqm-5.pickle (offline)")
    fe.add_argument("--backbone-file", metavar="PATH",
                    help="local r3d_18-b3b3357e.pth to put into the torch hub cache")
    fe.add_argument("--no-backbone", action="store_true", help="fetch omega/alpha only")
    ve = wsub.add_parser("verify", help="check sha256 of the cached (or given) files")
    ve.add_argument("paths", nargs="*", help="weights or backbone files (default: the caches)")
    inf = wsub.add_parser("info", help="describe a weights file (or the cache)")
    inf.add_argument("path", nargs="?", help="weights file")
    from .calibration import cli as calibration_cli  # light: pandas/scipy load on use

    calibration_cli.register(sub)
    return parser


def _metrics(args: argparse.Namespace, variants: list[str]) -> list[Any]:
    from .metric import CGVQM

    set_threads(args)
    out = []
    for v in variants:
        out.append(CGVQM(v, weights=args.weights, backbone=args.backbone,
                         random_backbone=args.random_backbone, device=args.device,
                         precision=args.precision, patch_scale=args.patch_scale,
                         batch_size=args.batch_size, seamless=args.seamless,
                         tf32_stem=args.fast_stem))
        if args.weights and args.weights != "uniform":
            break  # a weights file fixes the variant
    return out  # random backbone / uniform weights: the library logs a warning line


def _cmd_metrics(args: argparse.Namespace) -> int:
    from .metrics import metric_table_rows

    rows = metric_table_rows()
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    print(f"{'name':<10} {'direction':<14} {'kind':<6} {'range':<12} available here")
    for r in rows:
        avail = (f"yes ({r['reason']})" if r["reason"] else "yes") if r["available"] else (
            f"no: {r['reason']}")
        print(f"{r['name']:<10} {r['direction']:<14} {r['kind']:<6} {r['range']:<12} {avail}")
    return 0


def _alignment(args: argparse.Namespace) -> str:
    """How the test was fitted to the reference ("" if it was not; headers only)."""
    from .stream import alignment_note, open_input

    conv = on_conversion(args)
    return alignment_note(open_input(args.ref, fps=args.fps, on_conversion=conv),
                          open_input(args.test, fps=args.fps, on_conversion=conv))


def _score_row(res: Any, metric: Any, args: argparse.Namespace, note: str) -> dict[str, Any]:
    """The ``score --csv`` row of a CGVQM result: the columns a batch row has, but the key
    (a single pair is not resumed)."""
    from .batch import canonical_json
    from .metrics.cgvqm_entry import cgvqm_provenance, cgvqm_settings, metric_name, metric_title

    prov = cgvqm_provenance(metric)
    return {**_pair_columns(args), "metric": metric_name(metric), "title": metric_title(metric),
            "score": f"{res.q:.8g}",
            "direction": "higher-better", "pooling": res.pool, "patches": res.n_patches,
            "seconds": f"{res.seconds:.3f}", "note": note,
            **{k: prov[k] for k in ("backbone", "backbone_sha256", "weights_sha256")},
            "settings": canonical_json({**cgvqm_settings(metric),
                                        "device_type": metric.net.device.type}),
            "versions": canonical_json({k: v for k, v in prov.items() if k not in (
                "backbone", "backbone_sha256", "weights_sha256")})}


def _csv_before_scoring(args: argparse.Namespace, metric: str, pooling: str) -> Any:
    """``score --csv``: read the file before any scoring (a folder, a file that is not a
    scores CSV, refused in one line) and refuse a second row for the same metric, pooling
    and test: ``score`` rows carry no resume key, so a rerun cannot be told a duplicate of
    the row there and would only add one the analysis ignores."""
    if not args.csv:
        return None
    from .batch import read_scores

    state = read_scores(Path(args.csv), flag="--csv")
    pool = f" ({pooling})" if pooling else ""
    stimulus = _row_ids(args)[0]
    if (metric, pooling, stimulus) in state.slots:
        raise CGVQMError(f"--csv {args.csv}: already holds a score of {metric}{pool} for "
                         f"{stimulus}; score --csv adds one row per metric, pooling and test "
                         "and never a second: use a new --csv (or remove that row)")
    return state


def _cmd_score_peer(args: argparse.Namespace, name: str) -> int:
    """Any registry metric other than CGVQM: one pair, one line (or JSON)."""
    from .batch import Appender, canonical_json
    from .metrics import build_scorers, score_reference

    set_threads(args)
    options = metric_options(args, [args.pool])
    (scorer,) = build_scorers([name], options)
    state = _csv_before_scoring(args, scorer.name, "")
    (results,) = score_reference(args.ref, [args.test], [scorer], device=args.device,
                                 fps=args.fps, allow_resample=args.allow_resample,
                                 on_conversion=on_conversion(args),
                                 progress=sys.stderr.isatty(), strict=args.strict)
    (m,) = results
    if args.json:
        out = m.to_dict()
        out.update({"settings": {**scorer.settings(), "device_type": device_type(args)},
                    "provenance": scorer.provenance()})
        print(json.dumps(out))
    elif m.score is None:
        print(f"{m.metric}: {m.note}")
    else:
        print(f"{m.metric} = {m.score:.6g} ({m.direction}; mean of "
              f"{len(m.per_frame or [])} frames)" if m.per_frame else
              f"{m.metric} = {m.score:.6g} ({m.direction})")
    if args.csv:
        prov = scorer.provenance()
        app = Appender(Path(args.csv), state, flag="--csv")
        try:
            app.write([{**_pair_columns(args), "metric": m.metric, "title": scorer.title,
                        "direction": m.direction,
                        "note": m.note,
                        "score": "" if m.score is None else f"{m.score:.8g}",
                        "seconds": f"{m.extra.get('seconds', 0):.3f}",
                        "settings": canonical_json({**scorer.settings(),
                                                    "device_type": device_type(args)}),
                        **{k: prov.get(k, "") for k in ("backbone", "backbone_sha256",
                                                         "weights_sha256")},
                        "versions": canonical_json({k: v for k, v in prov.items() if k not in (
                            "backbone", "backbone_sha256", "weights_sha256")})}])
        finally:
            app.close()
    return 0


def device_type(args: argparse.Namespace) -> str:
    """"cpu" or "cuda" (what a batch row's settings record; the index is not a setting)."""
    return str(args.device or "cpu").split(":")[0]


def _pair_columns(args: argparse.Namespace) -> dict[str, str]:
    """What a ``score --csv`` row records of its inputs, as a batch row does: their names
    and sha256 (a row that names only a file cannot tell which render it scored)."""
    from stimuli_manifests import sha256_path

    stimulus, reference = _row_ids(args)
    return {"stimulus": stimulus, "reference": reference,
            "reference_sha256": sha256_path(args.ref), "stimulus_sha256": sha256_path(args.test)}


def _row_ids(args: argparse.Namespace) -> tuple[str, str]:
    """The stimulus and reference ids a ``score --csv`` row names: ``--id`` and
    ``--reference-id``, else the files' stems (which a manifest's ids rarely are)."""
    return (args.id or Path(args.test).stem, args.reference_id or Path(args.ref).stem)


def _refuse_mismatched_pair(args: argparse.Namespace) -> None:
    """--strict: compare the two headers' frame counts before the network is built."""
    from .stream import check_frame_count, open_input

    conv = on_conversion(args)
    ref = open_input(args.ref, fps=args.fps, name="reference", on_conversion=conv)
    test = open_input(args.test, fps=args.fps, name="test", on_conversion=conv)
    check_frame_count(ref, test, strict=True)


def _refuse_emap_over_inputs(args: argparse.Namespace) -> None:
    """An error map written over the video (or into the frame folder) being scored would
    destroy the input, and a later score of the same pair would silently differ."""
    inputs = [Path(p).resolve() for p in (args.ref, args.test) if isinstance(p, str | Path)]
    if args.emap and Path(args.emap).resolve() in inputs:
        raise CGVQMError(f"--emap {args.emap} is an input of this run; write the error map "
                         "elsewhere")
    if args.emap_png:
        folder = Path(args.emap_png).resolve()
        for given in inputs:
            if given == folder or (given.parent == folder and given.suffix.lower() == ".png"):
                raise CGVQMError(f"--emap-png {args.emap_png} is the frame folder of an input "
                                 "of this run; write the error-map frames into another folder")


def _refuse_self_scoring(args: argparse.Namespace) -> None:
    """A reference scored against itself gives a perfect score that looks like a result
    (a path typed twice, or a link to it)."""
    ref, test = Path(str(args.ref)).expanduser(), Path(str(args.test)).expanduser()
    if ref.exists() and test.exists() and ref.resolve() == test.resolve():
        raise CGVQMError(f"--ref and --test are the same file ({ref.resolve()}); give the test "
                         "video to score against this reference")


def _carries_rate(path: str) -> bool:
    """A video file has its own frame rate; a PNG folder or a .npy array has none."""
    p = Path(path).expanduser()
    return p.is_file() and p.suffix.lower() != ".npy"


def _refuse_fps_for_files(args: argparse.Namespace) -> None:
    """--fps gives PNG folders and .npy arrays their rate; video files keep their own, so
    with two of them it would change nothing."""
    if args.fps is not None and _carries_rate(args.ref) and _carries_rate(args.test):
        raise CGVQMError(f"--fps {args.fps:g}: both inputs are video files, which carry their "
                         "own frame rate; --fps applies to PNG folders and .npy arrays only")


def _rate_for_frames(args: argparse.Namespace) -> None:
    """Without --fps, frames that carry no rate take the other input's (a 25 fps video's
    frames are 25 fps); with neither carrying one, 30 fps is assumed, and said: the rate sets
    CGVQM's clip length, so a 24 fps render scored as 30 gets another score."""
    if args.fps is not None:
        return
    from .stream import open_input

    known = [p for p in (args.ref, args.test) if _carries_rate(p)]
    if len(known) == 1:
        args.fps = open_input(known[0], on_conversion="quiet").info.fps
        log.info("the frames without a rate of their own take %s's %g fps", known[0],
                 args.fps)
    elif not known:
        log.warning("%s and %s carry no frame rate: 30 fps assumed (it sets CGVQM's clip "
                    "length); give --fps for frames rendered at another rate", args.ref,
                    args.test)


def _cmd_score(args: argparse.Namespace) -> int:
    """``--csv``: the file is held from reading it to the row written (one writer at a time)."""
    for flag, value in (("--id", args.id), ("--reference-id", args.reference_id)):
        if value is not None and not args.csv:
            raise CGVQMError(f"{flag} names the row score --csv writes; give --csv too")
        if value is not None and (not value.strip() or value != value.strip()):
            raise CGVQMError(f"{flag} {value!r}: give the id as the manifest writes it, "
                             "without surrounding spaces")
    if not args.csv:
        return _score_pair(args)
    from .batch import scores_lock

    with scores_lock(args.csv, flag="--csv"):
        return _score_pair(args)


def _score_pair(args: argparse.Namespace) -> int:
    from .batch import Appender
    from .metrics.cgvqm_entry import metric_name

    check_options(args)
    _refuse_self_scoring(args)
    name = (args.metric or args.variant or "cgvqm-2").strip().lower()
    if args.metric and args.variant and args.metric != args.variant:
        raise CGVQMError("give --metric or --variant, not both")
    if args.strict:
        _refuse_mismatched_pair(args)
    from .metrics import get_entry

    get_entry(name)  # an unknown name first, with the list
    refuse_unread_options(args, [name])
    _refuse_fps_for_files(args)
    _rate_for_frames(args)
    if name not in ("cgvqm-2", "cgvqm-5"):
        if args.emap or args.emap_png:
            raise CGVQMError(f"error maps are written for CGVQM only, not {name}")
        if args.timing:
            raise CGVQMError(f"--timing is offered for CGVQM only, not {name}")
        return _cmd_score_peer(args, name)
    _refuse_emap_over_inputs(args)
    (name,) = _variant_of_weights(args, [name], bool(args.metric or args.variant))
    (metric,) = _metrics(args, [name])
    state = _csv_before_scoring(args, metric_name(metric), args.pool)
    clock = StageClock(metric.net.device) if args.timing else None
    res = metric.score(args.ref, args.test, pool=args.pool, fps=args.fps,
                       allow_resample=args.allow_resample, emap=args.emap or False,
                       emap_png_dir=args.emap_png, on_conversion=on_conversion(args),
                       progress=sys.stderr.isatty(), strict=args.strict, clock=clock)
    if clock is not None:
        print(f"timing: {clock.report()}", file=sys.stderr)
    note = _alignment(args) if (args.json or args.csv) else ""
    if args.json:
        out = {"metric": metric_name(metric), **res.to_dict(patches=True)}
        if note:
            out["note"] = note
        if clock is not None:
            out["timing"] = {k: round(v, 6) for k, v in clock.seconds().items()}
        print(json.dumps(out))
    else:
        tag = " [RANDOM BACKBONE]" if res.is_random_backbone else ""
        if metric.weights.kind == "uniform":
            tag += " [UNIFORM WEIGHTS]"
        if metric.seamless:
            tag += " [SEAMLESS: not upstream-identical]"
        print(f"{metric_name(metric)} q = {res.q:.3f} ({res.label}; {res.pool} pooling, "
              f"{res.n_patches} patches, {res.seconds:.1f} s){tag}")
        if res.q_anchored is not None:
            print(f"calibrated to the study scale: {res.q_anchored:.2f} "
                  f"({quality_label(res.q_anchored)})")
        else:
            fitted = (metric.weights.provenance or {}).get("anchoring")
            if isinstance(fitted, dict) and fitted.get("pool") not in (None, res.pool):
                print(f"no study-scale score: {Path(str(metric.weights.source)).name} was "
                      f"calibrated for {fitted['pool']} pooling, this is {res.pool}")
        if args.emap:
            print(f"error map written to {args.emap}")
    if args.csv:
        app = Appender(Path(args.csv), state, flag="--csv")
        try:
            app.write([_score_row(res, metric, args, note)])
        finally:
            app.close()
    return 0


def _variant_of_weights(args: argparse.Namespace, names: list[str], asked: bool) -> list[str]:
    """A --weights file fixes the CGVQM variant: without a request it is the file's; a
    request for another variant, or for both, is refused (each row would carry the file's
    variant, some twice)."""
    if args.weights in (None, "uniform"):
        return names
    from .weights import resolve_weights

    held = resolve_weights(args.weights).variant
    variants = [n for n in names if n in ("cgvqm-2", "cgvqm-5")]
    if not asked:
        return [held]
    if variants and variants != [held]:
        raise CGVQMError(f"--weights {args.weights} holds {held} weights, but "
                         f"{' and '.join(variants)} {'was' if len(variants) == 1 else 'were'} "
                         f"asked for: ask for {held} alone among the CGVQM variants")
    return names


def _cmd_batch(args: argparse.Namespace) -> int:
    """Progress: a bar on a terminal, plain lines where stderr is a log file."""
    from .batch import score_manifest
    from .metrics import parse_metric_list
    from .progress import for_stderr

    cluster = ray_settings(args, args.device)  # no Ray: says so before any work
    check_options(args)
    requested = [args.metrics] if args.metrics else []
    requested += list(args.variant or [])
    pools = list(dict.fromkeys(args.pool or ["max"]))
    options = metric_options(args, pools)
    names = _variant_of_weights(args, parse_metric_list(requested or ["cgvqm-2"], options),
                                bool(requested))
    refuse_unread_options(args, names, options)
    set_threads(args)
    if cluster is None:
        run = score_manifest
    else:
        from .distributed import score_manifest as score_on_ray

        run = partial(score_on_ray, settings=cluster)
    s = run(args.manifest, args.out, names, options,
            include_references=args.include_references, root=args.root,
            group_size=args.group_size, allow_resample=args.allow_resample,
            on_conversion=on_conversion(args), strict=args.strict, progress=for_stderr())
    print(f"{s.scored} scored, {s.skipped} already in {args.out}, {s.rows} rows written "
          f"({', '.join(names)})")
    for name in s.not_applicable:
        print(f"{name}: not applicable at this stimulus size (rows written without a score)")
    if cluster is not None:
        print(f"ray: {s.submitted} of {s.units} work unit(s) run on {len(s.nodes)} node(s)")
        if s.failed:
            raise CGVQMError(s.failure_message(args.out))
    return 0


def _backbone_beside_weights(args: argparse.Namespace) -> None:
    """``fetch --from DIR`` is an offline fetch: the backbone comes from DIR too when it is
    there, and when it is neither there nor cached, nothing is copied (a download attempt
    after copying the weights would report half a fetch as a failure)."""
    from . import hub

    if args.source is None or args.no_backbone or args.backbone_file:
        return
    beside = Path(args.source).expanduser() / hub.BACKBONE_FILE
    if beside.is_file():
        args.backbone_file = str(beside)
    elif not hub.hub_checkpoint_path().is_file():
        raise CGVQMError(f"--from {args.source}: it holds no {hub.BACKBONE_FILE} (the R3D-18 "
                         "backbone) and the torch hub cache has none: give --backbone-file "
                         "PATH, or --no-backbone to copy the weights only")


def _cmd_weights(args: argparse.Namespace) -> int:
    from . import hub, weights

    action = args.weights_command
    if action == "fetch":
        if args.no_backbone and args.backbone_file:
            raise CGVQMError("--backbone-file is for the backbone, which --no-backbone skips: "
                             "drop one of them")
        if not args.no_backbone and args.backbone_file and not Path(
                args.backbone_file).expanduser().is_file():  # before anything is copied
            raise CGVQMError(f"--backbone-file {args.backbone_file}: no such file")
        _backbone_beside_weights(args)
        for v in weights.VARIANTS:
            path = weights.fetch_upstream(v, source_dir=args.source)
            print(f"{v}: {path} (sha256 verified)")
        if not args.no_backbone:
            path = hub.fetch_backbone(source=args.backbone_file)
            print(f"backbone: {path}")
        return 0
    if action == "verify":
        paths = [Path(p) for p in args.paths] or [
            *(weights.cache_dir() / v.file_name for v in weights.VARIANTS.values()),
            hub.hub_checkpoint_path()]
        bad: list[str] = []
        for p in paths:
            if not p.is_file():
                print(f"{p}: {'a folder, not a file' if p.is_dir() else 'missing'}")
                bad.append(str(p))
                continue
            if p.suffix == ".pth":
                bb = hub.load_backbone_file(p)
                print(f"{p}: ok (backbone, sha256 {bb.sha256})")
            else:
                w = weights.resolve_weights(p)
                print(f"{p}: ok ({w.variant}, {w.kind}, sha256 {w.sha256})")
        if bad:
            raise CGVQMError(f"{len(bad)} file(s) missing ({', '.join(bad[:3])}"
                             f"{', ...' if len(bad) > 3 else ''}); run `cgvqm weights fetch` "
                             "(see --help)")
        return 0
    if action == "info":
        if args.path:
            w = weights.resolve_weights(args.path)
            a = abs(w.omega)
            print(json.dumps({"path": args.path, "variant": w.variant, "kind": w.kind,
                              "n_channels": int(w.omega.size), "n_levels": w.n_levels,
                              "alpha": w.alpha, "sha256": w.sha256,
                              "negative_fraction": float((w.omega < 0).mean()),
                              "abs_omega_sum": float(a.sum()),
                              "abs_omega_per_level": [float(x.sum())
                                                      for x in w.level_weights()],
                              "provenance": w.provenance}, indent=1))
            return 0
        print(f"weights cache: {weights.cache_dir()}")
        for v in weights.VARIANTS.values():
            p = weights.cache_dir() / v.file_name
            print(f"  {v.name}: {'present' if p.is_file() else 'missing'} ({v.sha256[:12]}...)")
        p = hub.hub_checkpoint_path()
        print(f"backbone: {p} ({'present' if p.is_file() else 'missing'})")
        print(f"published weights: IntelLabs/cgvqm@{weights.UPSTREAM_COMMIT}")
        return 0
    print("usage: cgvqm weights {fetch,verify,info} (see --help)", file=sys.stderr)
    return 2


def _dispatch(args: argparse.Namespace) -> int:
    if args.command == "metrics":
        return _cmd_metrics(args)
    if args.command == "score":
        return _cmd_score(args)
    if args.command == "batch":
        return _cmd_batch(args)
    if args.command == "calibrate":
        from .calibration import cli as calibration_cli

        return calibration_cli.run(args)
    return _cmd_weights(args)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("cgvqm: %(levelname)s: %(message)s"))
    loggers = [logging.getLogger(n) for n in ("cgvqm_core", "stimuli_manifests")]
    saved = [(lg.level, lg.propagate) for lg in loggers]
    for lg in loggers:
        lg.addHandler(handler)
        lg.setLevel(logging.INFO if args.verbose else logging.WARNING)
        lg.propagate = False
    try:
        return run_command("cgvqm", lambda: _dispatch(args), extra="metric",
                           interrupted="interrupted (batch runs resume where they stopped)",
                           sigterm_interrupts=True)
    finally:
        for lg, (level, propagate) in zip(loggers, saved, strict=True):
            lg.removeHandler(handler)
            lg.setLevel(level)
            lg.propagate = propagate


if __name__ == "__main__":
    sys.exit(main())
