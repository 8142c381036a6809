"""``cgvq-study serve STUDY``: deliver the study, collect uploads, show the dashboard."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from session_store.protocol import CLIENT_BATCH_BYTES

MIN_MAX_BODY = CLIENT_BATCH_BYTES + 64 * 1024
"""The app's largest batch of entries plus room for the request around it."""

NAME = "serve"
EXTRA = "server"
HELP = "serve a study to remote participants: downloads, live uploads, dashboard"


def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("study", type=Path, help="study folder (holds manifest.json)")
    parser.add_argument("--host", default="127.0.0.1",
                        help="address to listen on (default 127.0.0.1; another address needs "
                             "TLS or --insecure)")
    parser.add_argument("--port", type=int, default=8000, help="port (default 8000; 0: any)")
    parser.add_argument("--certfile", type=Path, default=None, help="TLS certificate (PEM)")
    parser.add_argument("--keyfile", type=Path, default=None, help="TLS private key (PEM)")
    parser.add_argument("--insecure", action="store_true",
                        help="allow plain HTTP on a non-loopback address")
    parser.add_argument("--behind-proxy", default=None, metavar="ADDRESSES",
                        help="trust X-Forwarded-For/-Proto from these proxy addresses "
                             "(comma-separated; e.g. 127.0.0.1) and mark cookies Secure")
    parser.add_argument("--new-version", action="store_true",
                        help="serve a changed manifest as a new version while sessions run on "
                             "the old one (they finish on theirs)")
    parser.add_argument("--stats-every", type=float, default=30.0, metavar="S",
                        help="recompute the dashboard's statistics at most every S seconds "
                             "(default 30)")
    parser.add_argument("--target-raters", type=int, default=None, metavar="N",
                        help="raters wanted per stimulus (default: everyone invited)")
    parser.add_argument("--rate", type=float, default=10.0, metavar="R",
                        help="requests per second per participant token (default 10)")
    parser.add_argument("--burst", type=float, default=60.0, metavar="B",
                        help="burst of requests per token (default 60)")
    addresses = parser.add_mutually_exclusive_group()
    addresses.add_argument("--keep-addresses", action="store_true",
                           help="keep each participant's last client address (IP) in the "
                                "server's database, to trace abuse (default: none is kept)")
    addresses.add_argument("--no-addresses", action="store_true",
                           help="keep no client address (the default; kept for scripts)")
    parser.add_argument("--max-body", type=int, default=None, metavar="BYTES",
                        help="largest request body (default 1 MiB; at least 576 KiB, the "
                             "app's upload batches)")
    stop = parser.add_argument_group("stopping rule (shown on the dashboard)")
    stop.add_argument("--target-mean-ci", type=float, default=None, metavar="W",
                      help="target: mean DMOS 95%% CI width over the conditions at most W "
                           "(on the rating scale)")
    stop.add_argument("--target-max-ci", type=float, default=None, metavar="W",
                      help="target: widest DMOS 95%% CI at most W")
    stop.add_argument("--target-ratings", type=int, default=None, metavar="N",
                      help="target: a budget of N ratings")
    stop.add_argument("--close-at-target", action="store_true",
                      help="take no new participants once the target is reached (those who "
                           "started finish)")


def run(args: argparse.Namespace) -> int:
    from session_store.errors import StudyError
    from study_server.config import ServerConfig
    from study_server.serve import Listen, serve
    from study_server.stopping import StoppingTarget

    for flag, value in (("--stats-every", args.stats_every), ("--rate", args.rate)):
        if not (math.isfinite(value) and value > 0):
            raise StudyError(f"{flag} must be a positive number, got {value:g}")
    if not (math.isfinite(args.burst) and args.burst >= 1):
        raise StudyError(f"--burst must be a number of at least 1, got {args.burst:g}")
    if args.target_raters is not None and args.target_raters < 1:
        raise StudyError(f"--target-raters must be at least 1 (leave it out to want everyone "
                         f"invited), got {args.target_raters}")
    config = ServerConfig(study=args.study, new_version=args.new_version,
                          stats_every_s=args.stats_every, target_raters=args.target_raters,
                          rate_per_s=args.rate, burst=args.burst,
                          secure_cookies=args.behind_proxy is not None,
                          store_addresses=args.keep_addresses)
    for flag, value in (("--target-mean-ci", args.target_mean_ci),
                        ("--target-max-ci", args.target_max_ci)):
        if value is not None and not (0 < value < float("inf")):
            raise StudyError(f"{flag} must be a positive width, got {value:g}")
    if args.target_ratings is not None and args.target_ratings < 1:
        raise StudyError(f"--target-ratings must be at least 1, got {args.target_ratings}")
    config.stopping = StoppingTarget(args.target_mean_ci, args.target_max_ci,
                                     args.target_ratings, args.close_at_target)
    if args.close_at_target and not config.stopping.is_set:
        raise StudyError("--close-at-target needs a target (--target-mean-ci, --target-max-ci "
                         "or --target-ratings)")
    if args.max_body is not None:
        if args.max_body < MIN_MAX_BODY:
            raise StudyError(f"--max-body below {MIN_MAX_BODY // 1024} KiB would refuse the "
                             f"app's upload batches (up to {CLIENT_BATCH_BYTES // 1024} KiB of "
                             "entries), and a refused batch stops that participant's uploads")
        config.max_body_bytes = args.max_body
    listen = Listen(host=args.host, port=args.port, certfile=args.certfile,
                    keyfile=args.keyfile, insecure=args.insecure, proxy=args.behind_proxy)

    def ready(url: str, token: str, created: bool) -> None:
        print(f"serving study {args.study} at {url}", flush=True)
        print(f"dashboard: {url}/dashboard", flush=True)
        kept = f"{args.study}/server/admin_token"
        if created and sys.stdout.isatty():
            print(f"admin token (generated, kept in {kept}): {token}", flush=True)
        elif created:  # a service's log would keep the secret for anyone who reads it
            print(f"admin token: generated and kept in {kept} (owner-only; not printed "
                  "where the output is not a terminal)", flush=True)
        else:
            print("admin token: $CGVQ_ADMIN_TOKEN or the file server/admin_token in the study "
                  "folder", flush=True)
        print("stop with Ctrl-C", file=sys.stderr, flush=True)

    serve(config, listen, ready)
    return 0
