"""``cgvq-study simulate``: simulated participants with known truth, as session files, and
optionally uploading to a study server as they rate (through the app's upload client)."""

from __future__ import annotations

import argparse
import math
import re

NAME = "simulate"
HELP = "simulate a panel of raters (SUREAL generative model) into session files"


def _offline(text: str) -> tuple[str, float, float]:
    m = re.fullmatch(r"([A-Za-z0-9][A-Za-z0-9._-]*):(\d+(?:\.\d+)?):(\d+(?:\.\d+)?)", text)
    if not m or float(m.group(2)) >= float(m.group(3)):
        raise argparse.ArgumentTypeError(
            f"{text!r}: use PARTICIPANT:FROM:UNTIL in seconds after the start (e.g. P03:5:40)")
    return m.group(1), float(m.group(2)), float(m.group(3))


def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--manifest", required=True, help="the study's manifest.json")
    parser.add_argument("--raters", type=int, required=True, help="number of raters")
    parser.add_argument("--outliers", type=int, default=0,
                        help="how many of them are outlier raters (default 0)")
    parser.add_argument("--outlier-kind", choices=("random", "inverted", "mixed"),
                        default="random", help="how outliers answer (default random)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the whole simulation")
    parser.add_argument("--colour-failures", type=int, default=0, metavar="N",
                        help="simulated raters who fail the colour-vision check, when the "
                             "manifest's panel screens colour vision (default 0)")
    parser.add_argument("--repetitions", type=int, default=None,
                        help="repetitions per stimulus (default: the manifest's protocol)")
    parser.add_argument("--out", required=True,
                        help="folder for the session files and ground_truth.json "
                             "(e.g. STUDY/simulated: keep them apart from real sessions)")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace sessions simulated into --out before")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    up = parser.add_argument_group("uploading to a study server")
    up.add_argument("--server", default=None, metavar="URL",
                    help="upload every session to this study server while rating (all raters "
                         "at once, real times); needs --invites")
    up.add_argument("--invites", default=None, metavar="CSV",
                    help="the invites CSV of 'cgvq-study invite' (ids and tokens, in order)")
    up.add_argument("--pace", type=float, default=0.0, metavar="S",
                    help="seconds between two ratings of a rater (default 0)")
    up.add_argument("--stagger", type=float, default=0.0, metavar="S",
                    help="rater k starts k*S seconds after the first (default 0: all at "
                         "once), as participants arriving over time")
    up.add_argument("--offline", type=_offline, action="append", default=[],
                    metavar="ID:FROM:UNTIL",
                    help="this rater's network is down from FROM to UNTIL seconds after the "
                         "start (repeatable)")
    up.add_argument("--upload-timeout", type=float, default=600.0, metavar="S",
                    help="how long to wait at the end for every upload (default 600)")
    up.add_argument("--after-refit", action="store_true",
                    help="adaptive studies: the raters after the warm-up arrive only once the "
                         "server has refit its model, as participants arriving over days find "
                         "it (a fast simulation would otherwise outrun the first refit); needs "
                         "$CGVQ_ADMIN_TOKEN")


def run(args: argparse.Namespace) -> int:
    from session_store.errors import StudyError
    from study_app.simulate import SimulationOptions, UploadOptions, run_simulation

    if args.seed < 0:
        raise StudyError(f"--seed {args.seed}: use a non-negative integer")
    if (args.server is None) != (args.invites is None):
        raise StudyError("--server and --invites go together")
    for flag, value in (("--pace", args.pace), ("--stagger", args.stagger)):
        if not (math.isfinite(value) and value >= 0):
            raise StudyError(f"{flag} must be a number of seconds, 0 or more, got {value:g}")
    if not (math.isfinite(args.upload_timeout) and args.upload_timeout > 0):
        raise StudyError(f"--upload-timeout must be a positive number of seconds, got "
                         f"{args.upload_timeout:g}")
    _refuse_ignored(args)
    opts = SimulationOptions(raters=args.raters, outliers=args.outliers,
                             outlier_kind=args.outlier_kind, seed=args.seed,
                             repetitions=args.repetitions,
                             colour_failures=args.colour_failures)
    upload = None
    if args.server is not None:
        from session_store.invite import read_invites

        invites = read_invites(args.invites)
        invited = [i.participant for i in invites[:args.raters]]
        strangers = sorted({pid for pid, _, _ in args.offline} - set(invited))
        if strangers:
            raise StudyError(f"--offline {strangers[0]}: not one of the {len(invited)} raters "
                             f"simulated here ({', '.join(invited[:3])}"
                             f"{', ...' if len(invited) > 3 else ''}, from {args.invites})")
        opts.check()
        _check_server(args.server, invites[0] if invites else None)
        upload = UploadOptions(server=args.server,
                               tokens={i.participant: i.token for i in invites},
                               pace_s=args.pace, stagger_s=args.stagger,
                               timeout_s=args.upload_timeout,
                               offline={pid: (a, b) for pid, a, b in args.offline},
                               start_gate=_refit_gate(args) if args.after_refit else None)
    result = run_simulation(args.manifest, args.out, opts, overwrite=args.overwrite,
                            progress=not args.no_progress, upload=upload)
    print(f"wrote {args.raters} session files and the ground truth {result.truth_path}")
    if upload is None:
        return 0
    missing = {p: s for p, s in result.upload.items() if not s.all_arrived}
    print(f"uploaded to {args.server}: {len(result.upload) - len(missing)} of "
          f"{len(result.upload)} sessions arrived completely")
    for pid, st in missing.items():
        print(f"  {pid}: {st.acked_seq} of {st.local_seq} entries arrived ({st.state}: "
              f"{st.error})", flush=True)
    if missing:
        raise StudyError(f"{len(missing)} of {len(result.upload)} sessions did not arrive "
                         f"completely at {args.server} within --upload-timeout "
                         f"{args.upload_timeout:g} s (see the report on stdout); the session files "
                         f"are in {args.out}")
    return 0


def _refuse_ignored(args: argparse.Namespace) -> None:
    """Options that would change nothing in this run are refused, not silently dropped."""
    from session_store.errors import StudyError

    if args.server is None:
        given = [flag for flag, on in (("--pace", args.pace != 0), ("--stagger", args.stagger != 0),
                                       ("--offline", bool(args.offline)),
                                       ("--after-refit", args.after_refit),
                                       ("--upload-timeout", args.upload_timeout != 600.0)) if on]
        if given:
            raise StudyError(f"{given[0]} applies to uploads to a study server: add --server "
                             "and --invites, or drop it")
    if args.outlier_kind != "random" and args.outliers == 0:
        raise StudyError(f"--outlier-kind {args.outlier_kind}: no outliers are simulated; add "
                         "--outliers N")


REFIT_WAIT_S = 600.0
"""How long a rater after the warm-up waits for the server's first refit (--after-refit)."""


def _refit_gate(args: argparse.Namespace):
    """The raters after the adaptive warm-up wait until the server has refit its model."""
    import os
    import threading
    import time

    from session_store.errors import StudyError
    from stimuli_manifests import load_manifest
    from study_app.remote.admin import server_refits
    from study_app.remote.http import ServerRefused, ServerUnavailable

    settings = load_manifest(args.manifest).manifest.protocol.adaptive_settings()
    if settings is None:
        raise StudyError(f"--after-refit: {args.manifest} is a full design (protocol."
                         "allocation 'full'); nothing is refit")
    token = os.environ.get("CGVQ_ADMIN_TOKEN", "")
    if not token:
        raise StudyError("--after-refit asks the server whether it has refit: set "
                         "$CGVQ_ADMIN_TOKEN to its admin token")
    refit = threading.Event()

    def gate(k: int) -> None:
        deadline = time.monotonic() + REFIT_WAIT_S
        while k >= settings.warmup_participants and not refit.is_set():
            try:
                n = server_refits(args.server, token)
            except ServerUnavailable:
                n = 0  # restarting: ask again
            except ServerRefused as exc:
                raise StudyError(f"--after-refit: the server refused the admin token "
                                 f"({exc})") from None
            if n is None:
                raise StudyError(f"--after-refit: {args.server} serves a full design")
            if n > 0:
                refit.set()
            elif time.monotonic() > deadline:
                raise StudyError(f"--after-refit: the server did not refit within "
                                 f"{REFIT_WAIT_S:g} s of rater {k + 1}'s arrival")
            else:
                time.sleep(0.5)

    return gate


def _check_server(server: str, first) -> None:
    """Before anything is written: the server answers, and knows the first invited token."""
    from session_store.protocol import participant_path
    from study_app.remote.http import ServerClient, ServerRefused, ServerUnavailable

    if first is None:
        return  # read_invites refuses an empty file; nothing to ask
    client = ServerClient(server, first.token)
    try:
        client.json("GET", participant_path(first.participant, "study"))
    except ServerUnavailable as exc:
        raise ServerUnavailable(f"--server: {exc}; start it (cgvq-study serve) or check the "
                                "address") from None
    except ServerRefused as exc:
        raise ServerRefused(f"--server {server} refused invited participant "
                            f"{first.participant} ({exc}); use the invites CSV of this server",
                            exc.status, exc.detail) from None
