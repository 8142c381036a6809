"""The end-to-end demo: from nothing to a report, with a simulated panel whose truth is known.

1. ``cgvq-study synth``: synthetic CG stimuli (two GLSL scenes x six families x 4 levels),
   and ``cgvq-study panel --add-templates``: the demographics questionnaire, the post-study
   survey and the colour-vision check in the manifest;
2. through the study server (``scripts/demo_server.py``): ``cgvq-study serve`` on 127.0.0.1,
   ``invite``, 20 simulated raters (one of them an outlier, one failing the colour check,
   all answering the questionnaires) uploading at once through the
   app's client (one offline for a while, the server SIGKILLed and restarted once), a
   dashboard screenshot (``dashboard.png``), ``pull`` of every session as received;
3. ``cgvqm batch --metrics all``: every metric of the registry available here (the PIQ-family
   image metrics, FLIP, ColorVideoVDP, CGVQM-2 and CGVQM-5; CGVQM with a flagged random
   backbone and uniform weights when the pretrained ones are not available offline)
   -> ``scores.csv``;
4. ``cgvq-analyze report`` -> ``report/report.html`` with ``dmos.csv`` beside it;
5. a check of the analysis against the simulation's truth, printed and saved as
   ``demo_summary.json``.

Every tool runs as its own process through its command line, exactly as a user would run it.
Usage: ``python scripts/run_demo.py [--out demo_output] [--size 128] [--seconds 1] ...``
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import stats

sys.path.insert(0, str(Path(__file__).resolve().parent))
import demo_server

REPO = Path(__file__).resolve().parents[1]
PRETRAINED_BACKBONE = "r3d_18-b3b3357e.pth"


def _run(step: str, cmd: list[str], log: list[dict], *,
         optional: bool = False) -> subprocess.CompletedProcess:
    """Run one step; an ``optional`` step that fails is reported as 'not available'."""
    print(f"\n=== {step}: {' '.join(Path(c).name if i == 0 else c for i, c in enumerate(cmd))}",
          flush=True)
    t0 = time.monotonic()
    # stdout and stderr reach the terminal as they come (progress bars); the end of stderr is
    # kept for the error message
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, cwd=REPO)
    tail = b""
    assert proc.stderr is not None
    while chunk := os.read(proc.stderr.fileno(), 4096):
        sys.stderr.buffer.write(chunk)
        sys.stderr.buffer.flush()
        tail = (tail + chunk)[-20000:]
    returncode = proc.wait()
    res = subprocess.CompletedProcess(cmd, returncode, None,
                                      tail.decode("utf-8", errors="replace"))
    seconds = time.monotonic() - t0
    log.append({"step": step, "seconds": round(seconds, 1), "returncode": res.returncode,
                "error": _last_error(res.stderr) if res.returncode else None,
                "optional": optional})
    print(f"--- {step}: {_outcome(res.returncode, optional)} in {seconds:.1f} s", flush=True)
    return res


def _outcome(returncode: int, optional: bool) -> str:
    if returncode == 0:
        return "ok"
    return "not available (the demo goes on without it)" if optional else "FAILED"


def _last_error(stderr: str) -> str:
    lines = [ln for ln in stderr.strip().splitlines() if ln.strip() and "%|" not in ln]
    return lines[-1] if lines else "(no message)"


def _pretrained_backbone_available() -> str | None:
    """Path of a local pretrained backbone (CGVQM_BACKBONE or the torch hub cache), if any."""
    env = os.environ.get("CGVQM_BACKBONE")
    if env and Path(env).is_file():
        return env
    try:
        import torch

        cached = Path(torch.hub.get_dir()) / "checkpoints" / PRETRAINED_BACKBONE
    except Exception:  # torch missing or hub dir unknown: treat as unavailable
        return None
    return str(cached) if cached.is_file() else None


def _published_weights_available(log: list[dict]) -> bool:
    """True when the authors' omega/alpha files are cached, local, or can be fetched now.

    With CGVQM_OFFLINE=1 the fetch looks only at the cache and CGVQM_WEIGHTS_DIR.
    """
    res = _run("looking for the published CGVQM weights",
               [*_cli("cgvqm_core.cli"), "weights", "fetch", "--no-backbone"], log,
               optional=True)
    return res.returncode == 0


def _cli(module: str) -> list[str]:
    return [sys.executable, "-m", module]


def _score(args, manifest: Path, out: Path, log: list[dict]) -> tuple[Path, list[str]]:
    """Every available registry metric in one ``cgvqm batch``; returns the CSV and notes."""
    notes: list[str] = []
    metrics = args.metrics
    extra = list(args.cgvqm_arg or [])
    backbone = None
    if args.no_cgvqm:
        notes.append("CGVQM was not run (--no-cgvqm).")
        if metrics == "all":
            from cgvqm_core.metrics import entries

            metrics = ",".join(e.spec.name for e in entries() if e.availability().ok
                               and not e.spec.name.startswith("cgvqm"))
    else:
        backbone = _pretrained_backbone_available()
        if not backbone:
            extra += ["--random-backbone", str(args.seed)]
        if not any(a.startswith("--weights") for a in extra) and not (
            _published_weights_available(log)
        ):
            extra += ["--weights", "uniform"]
            notes.append("The published CGVQM feature weights (omega, alpha) could not be "
                         "fetched offline, so CGVQM ran with UNIFORM feature weights (metric "
                         "names end in '-uniform'); put the two weight files in "
                         "CGVQM_WEIGHTS_DIR or run 'cgvqm weights fetch' to use them.")
    path = out / "scores.csv"
    path.unlink(missing_ok=True)
    res = _run("cgvqm batch (all metrics)",
               [*_cli("cgvqm_core.cli"), "batch", "--manifest", str(manifest), "--out",
                str(path), "--metrics", metrics, *extra], log)
    if res.returncode or not path.is_file():
        raise SystemExit(f"demo stopped: metric scoring failed: {_last_error(res.stderr)}")
    scores = pd.read_csv(path)
    ran = sorted({m for m in scores["metric"] if m.startswith("cgvqm")})
    if ran and backbone:
        notes.insert(0, f"{' and '.join(ran)} used the pretrained R3D-18 backbone from "
                        f"{backbone}.")
    elif ran:
        notes.insert(0, f"{' AND '.join(m.upper() for m in ran)} RAN ON AN UNTRAINED (RANDOM, "
                        f"seed {args.seed}) BACKBONE: the pretrained Kinetics-400 R3D-18 "
                        "weights were not available offline (set CGVQM_BACKBONE to a local "
                        "copy to use them). Their correlations with the simulated DMOS say "
                        "nothing about the published metric.")
    na = scores[scores["score"].isna()]
    for metric, g in na.groupby("metric"):
        notes.append(f"{metric}: {g['note'].iloc[0]} (no score; make the stimuli larger "
                     "with --size to include it).")
    timing = scores.groupby("metric", sort=False)["seconds"].mean()
    log.append({"step": "seconds per stimulus by metric",
                "per_metric": {k: round(float(v), 3) for k, v in timing.items()
                               if v == v}})
    return path, notes


def _families(truth: dict) -> str:
    """The distortion families the demo's manifest holds, in words (as simulated)."""
    levels: dict[str, set] = {}
    for st in truth["stimuli"]:
        if not st["is_hidden_reference"] and st["method"]:
            levels.setdefault(st["method"], set()).add(st["level"])
    counts = sorted({len(v) for v in levels.values()})
    at = f"{counts[0]}" if len(counts) == 1 else f"{counts[0]}-{counts[-1]}"
    names = ", ".join(m.replace("_", " ") for m in sorted(levels))
    n = len(levels)
    return f"{n} distortion famil{'y' if n == 1 else 'ies'} ({names}) at {at} levels each"


def _notes(args, truth: dict, cgvqm_notes: list[str]) -> str:
    outliers = [f"{r['participant']} ({r['outlier']})" for r in truth["raters"] if r["outlier"]]
    o = truth["options"]
    lines = [
        "THIS IS A DEMO ON SIMULATED DATA. No person rated these videos.",
        "",
        *cgvqm_notes,
        "",
        f"Stimuli: synthetic GLSL scenes ({', '.join(args.scenes.split(','))}) at "
        f"{args.size}x{args.size}, {args.seconds:g} s, rendered off-screen by 'cgvq-study "
        f"synth'; {_families(truth)}.",
        f"Ratings: {o['raters']} simulated raters x {truth['repetitions']} repetitions "
        "written as session files by 'cgvq-study simulate' and uploaded as they were given "
        "to 'cgvq-study serve', then pulled from it (SUREAL's generative model: "
        "true quality + rater bias + rater inconsistency x N(0,1) + content ambiguity x "
        f"N(0,1), clipped to the scale; seed {truth['seed']}).",
        f"Injected outlier rater(s): {', '.join(outliers) or 'none'}.",
        f"True quality: {truth['quality_model']['formula']}.",
        "The truth (quality per stimulus, biases, inconsistencies, ambiguities, outliers) is "
        "in participants/ground_truth.json.",
    ]
    return "\n".join(lines) + "\n"


ADAPTIVE = {"blocks": 3, "warmup_participants": 3, "refit_seconds": 1}
STAGGER_S = 2.0
"""In the adaptive demo the participants arrive one every 2 s, and those after the warm-up
only once the server has refit its model (``simulate --after-refit``): at the demo's pace the
whole panel would otherwise be done before the first refit, and every block uniform."""
"""The demo's adaptive design: block 1 (every stimulus once) and two planned blocks, as many
ratings as the full design's three repetitions."""


def _make_adaptive(manifest: Path) -> None:
    """Switch the demo study to adaptive allocation (before anyone is invited)."""
    from stimuli_manifests import fill_checksums, load_manifest, parse_manifest, save_manifest

    data = json.loads(manifest.read_text())
    data["protocol"].update({"allocation": "adaptive", "adaptive": ADAPTIVE})
    save_manifest(parse_manifest(data), manifest)
    save_manifest(fill_checksums(load_manifest(manifest)), manifest)


def _widths(dmos_csv: Path) -> dict:
    d = pd.read_csv(dmos_csv)
    ratings = int(d["n_ratings"].sum())  # the ratings behind the DMOS (after screening)
    d = d[~d["is_hidden_reference"].astype(bool)]
    w = d["ci95_high"] - d["ci95_low"]
    return {"mean_width": float(w.mean()), "max_width": float(w.max()), "ratings": ratings}


def _compare_with_full(args, manifest: Path, report: Path, out: Path,
                       log: list[dict]) -> dict:
    """The same simulated panel (same seed, same truth) rating the full design (every
    stimulus three times, no server): its DMOS interval widths against the adaptive ones."""
    from stimuli_manifests import parse_manifest, save_manifest

    full = out / "full_design"
    full.mkdir(parents=True, exist_ok=True)
    data = json.loads(manifest.read_text())
    data["protocol"]["allocation"] = "full"
    data["protocol"].pop("adaptive", None)
    data["root"] = str((manifest.parent / data.get("root", ".")).resolve())
    save_manifest(parse_manifest(data), full / "manifest.json")
    res = _run("simulate the full design", [
        *_cli("cgvq_cli.study_cli"), "simulate", "--manifest", str(full / "manifest.json"),
        "--raters", str(args.raters), "--outliers", str(args.outliers), "--seed",
        str(args.seed), "--repetitions", "3", "--out", str(full / "sessions"), "--overwrite",
        "--no-progress"], log)
    if res.returncode:
        raise SystemExit(1)
    res = _run("DMOS of the full design", [
        *_cli("analysis.cli"), "dmos", "--manifest", str(full / "manifest.json"),
        "--sessions", str(full / "sessions"), "--out", str(full / "dmos.csv"), "--seed",
        str(args.seed), "--bootstrap", str(args.bootstrap)], log)
    if res.returncode:
        raise SystemExit(1)
    adaptive, complete = _widths(report / "dmos.csv"), _widths(full / "dmos.csv")
    return {"adaptive": adaptive, "full": complete,
            "ratings_share": adaptive["ratings"] / complete["ratings"]}


def _check(truth: dict, report_dir: Path) -> dict:
    """How well the analysis recovered the simulated truth."""
    dmos = pd.read_csv(report_dir / "dmos.csv")
    summary = json.loads((report_dir / "summary.json").read_text())
    removed = sorted(r["rater"] for r in summary.get("removed_raters", []))
    injected = sorted(truth["outliers"])
    q = pd.DataFrame(truth["stimuli"]).set_index("id")["true_quality"]
    cond = dmos[~dmos["is_hidden_reference"].astype(bool)].copy()
    cond["true_quality"] = cond["stimulus"].map(q)
    srcc = float(stats.spearmanr(cond["dmos"], cond["true_quality"]).statistic)
    pairs = ordered = 0
    for _, g in cond.groupby(["reference", "method"]):
        g = g.sort_values("level")
        d = g["dmos"].to_numpy()
        pairs += 1
        ordered += bool(np.all(np.diff(d) > 0))
    raters = {r["participant"]: r for r in truth["raters"]}
    return {
        "injected_outliers": injected,
        "removed_raters": removed,
        "outliers_found": set(injected) <= set(removed),
        "false_alarms": [
            {"rater": r, "true_bias": raters.get(r, {}).get("bias"),
             "true_inconsistency": raters.get(r, {}).get("inconsistency")}
            for r in removed if r not in injected],
        "srcc_dmos_vs_true_quality": srcc,
        "series_in_true_level_order": ordered,
        "series": pairs,
        "metrics": summary.get("metrics", []),
        "untrained_backbone": summary.get("untrained_backbone", {}),
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description="Run the end-to-end demo.")
    p.add_argument("--out", default="demo_output", help="output folder (default demo_output)")
    p.add_argument("--size", type=int, default=128, help="frame size in pixels (default 128)")
    p.add_argument("--seconds", type=float, default=1.0, help="clip length (default 1)")
    p.add_argument("--scenes", default="colonnade,lattice")
    p.add_argument("--methods", default="all")
    p.add_argument("--raters", type=int, default=20)
    p.add_argument("--outliers", type=int, default=1)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--bootstrap", type=int, default=1000)
    p.add_argument("--splits", type=int, default=1000)
    p.add_argument("--metrics", default="all",
                   help="registry metrics to score (comma-separated; default all available)")
    p.add_argument("--no-cgvqm", action="store_true", help="leave CGVQM out of the scores")
    p.add_argument("--allocation", choices=("full", "adaptive"), default="full",
                   help="full: every rater rates every stimulus 3 times (default); adaptive: "
                        "block 1 every stimulus once, then two blocks planned by the study "
                        "server (as many ratings), compared with the full design")
    p.add_argument("--cgvqm-arg", action="append", metavar="ARG",
                   help="extra argument for 'cgvqm batch' (repeatable), e.g. --weights")
    args = p.parse_args(argv)

    t_start = time.monotonic()
    out = Path(args.out).resolve()
    study = out / "study"
    manifest = study / "manifest.json"
    out.mkdir(parents=True, exist_ok=True)
    log: list[dict] = []

    res = _run("synth", [*_cli("cgvq_cli.study_cli"), "synth", "--out", str(study), "--size",
                         str(args.size), "--seconds", str(args.seconds), "--scenes",
                         args.scenes, "--methods", args.methods, "--seed", str(args.seed),
                         "--overwrite"], log)
    if res.returncode:
        return _fail(log)
    res = _run("panel", [*_cli("cgvq_cli.study_cli"), "panel", str(study), "--add-templates"],
               log)
    if res.returncode:
        return _fail(log)
    if args.allocation == "adaptive":
        _make_adaptive(manifest)
    try:
        sessions, truth_path, server_facts = demo_server.collect(
            study, out, raters=args.raters, outliers=args.outliers, seed=args.seed, log=log,
            run=_run, stagger=STAGGER_S if args.allocation == "adaptive" else 0.0,
            after_refit=args.allocation == "adaptive")
    except SystemExit:
        return _fail(log)
    if not server_facts.get("all_arrived"):
        return _fail(log)
    truth = json.loads(truth_path.read_text())
    scores, cgvqm_notes = _score(args, manifest, out, log)
    notes = out / "notes.md"
    notes.write_text(_notes(args, truth, cgvqm_notes), encoding="utf-8")
    report = out / "report"
    res = _run("report", [*_cli("analysis.cli"), "report", "--manifest", str(manifest),
                          "--sessions", str(sessions), "--metric", str(scores), "--notes",
                          str(notes), "--out", str(report), "--seed", str(args.seed),
                          "--bootstrap", str(args.bootstrap), "--splits", str(args.splits)],
               log)
    if res.returncode:
        return _fail(log)
    check = _check(truth, report)
    check["server"] = server_facts
    if args.allocation == "adaptive":
        check["allocation"] = _compare_with_full(args, manifest, report, out, log)
    check["steps"] = log
    check["total_seconds"] = round(time.monotonic() - t_start, 1)
    (out / "demo_summary.json").write_text(json.dumps(check, indent=2) + "\n")

    print("\n=== demo summary")
    print(f"  study server: {server_facts['sessions_pulled']} sessions pulled, every upload "
          f"arrived; {server_facts['restarts']} restart; offline for a while: "
          f"{server_facts['offline_participant']}; flags: {server_facts['flags'] or 'none'}"
          + (f"; dashboard screenshot: {server_facts['dashboard_png']}"
             if server_facts.get("dashboard_png") else ""))
    if "allocation" in check:
        a = check["allocation"]
        print(f"  adaptive allocation: {a['adaptive']['ratings']} ratings, DMOS 95% CI width "
              f"mean {a['adaptive']['mean_width']:.2f}, widest {a['adaptive']['max_width']:.2f}"
              f"; the full design with the same simulated panel: {a['full']['ratings']} "
              f"ratings, mean {a['full']['mean_width']:.2f}, widest "
              f"{a['full']['max_width']:.2f} ({100 * a['ratings_share']:.0f} % of its ratings)")
    for line in cgvqm_notes:
        print(f"  NOTE: {line}")
    print(f"  injected outlier(s): {', '.join(check['injected_outliers']) or 'none'}; "
          f"removed by the analysis: {', '.join(check['removed_raters']) or 'none'} -> "
          f"{'all found' if check['outliers_found'] else 'NOT all found'}")
    for fa in check["false_alarms"]:
        print(f"  also removed: {fa['rater']} (a regular simulated rater: bias "
              f"{fa['true_bias']:+.1f}, inconsistency {fa['true_inconsistency']:.1f})")
    print(f"  DMOS vs true quality: SRCC {check['srcc_dmos_vs_true_quality']:.3f}; "
          f"{check['series_in_true_level_order']} of {check['series']} (source, method) "
          "series have DMOS strictly increasing with level")
    for m in check["metrics"]:
        print(f"  {m['metric']:>10}: PLCC {m.get('plcc', float('nan')):.3f}  "
              f"SRCC {m.get('srcc', float('nan')):.3f}")
    for step in log:
        if "per_metric" in step:
            per = ", ".join(f"{k} {v:.2f}" for k, v in step["per_metric"].items())
            print(f"  seconds per stimulus: {per}")
            continue
        outcome = _outcome(step["returncode"], step.get("optional", False))
        if step["returncode"]:
            outcome = f"{outcome.split(' (')[0]}: {step['error']}"
        print(f"  {step['step']:<26} {step['seconds']:7.1f} s  {outcome}")
    print(f"  total {check['total_seconds']:.0f} s; report: {report / 'report.html'}")
    return 0


def _fail(log: list[dict]) -> int:
    step = log[-1]
    print(f"demo stopped: step '{step['step']}' failed: {step['error']}", file=sys.stderr)
    return 1


if __name__ == "__main__":
    sys.exit(main())
