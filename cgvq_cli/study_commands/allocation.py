"""``cgvq-study allocation STUDY [--replay]``: the adaptive allocation's log, and its audit."""

from __future__ import annotations

import argparse
from pathlib import Path

NAME = "allocation"
HELP = ("show the adaptive allocation's log (every refit and every block issued); --replay "
        "recomputes them all and says whether they come out identical")


def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("study", type=Path, help="study folder (served before)")
    parser.add_argument("--replay", action="store_true",
                        help="refit every logged fit from the stored ratings and re-plan every "
                             "block from its logged inputs (exit 1 when anything differs)")


def run(args: argparse.Namespace) -> int:
    from session_store.errors import StudyError
    from session_store.study_folder import load_study
    from study_server.allocator import Allocator
    from study_server.storage import ServerStore, state_path

    folder = load_study(args.study).folder
    path = state_path(folder)
    if not path.is_file():
        raise StudyError(f"{folder} has not been served yet (no {path})")
    with ServerStore(path, create=False) as store:
        versions = [(current, a) for current, a in Allocator.every_version(store) if a.active]
        if not versions:
            alloc = Allocator.offline(store)  # refuses a study never served
            print(f"study {alloc.study_id}: full design (protocol.allocation is 'full'); "
                  "nothing is allocated")
            return 0
        problems: list[str] = []
        n_fits = n_blocks = 0
        for current, alloc in versions:
            fits, blocks = alloc.fits(), alloc.log_rows()
            n_fits, n_blocks = n_fits + len(fits), n_blocks + len(blocks)
            which = "" if len(versions) == 1 and current else (
                f", version {alloc.manifest_sha256[:12]}" + (" (current)" if current else ""))
            print(f"study {alloc.study_id}{which}: adaptive allocation, {len(fits)} refit(s), "
                  f"{len(blocks)} block(s) issued")
            _print_log(fits, blocks)
            if args.replay:
                problems += alloc.replay()
    if not args.replay:
        return 0
    if problems:
        for p in problems:
            print(f"  DIFFERS: {p}")
        print(f"the replay differs in {len(problems)} place(s)")
        return 1
    print(f"replayed {n_fits} fit(s) and {n_blocks} block(s): identical")
    return 0


def _print_log(fits: list[dict], blocks: list[dict]) -> None:
    for f in fits:
        fit = f["fit"]
        widths = "" if fit.get("mean_width") is None else (
            f"; DMOS 95 % CI width mean {fit['mean_width']:.2f}, max {fit['max_width']:.2f}")
        print(f"  fit {f['fit_id']} at {f['at']}: {fit['n_ratings']} ratings of "
              f"{fit['raters']} raters ({f['seconds']:.2f} s){widths}")
    for b in blocks:
        counts = sorted({b["stimuli"].count(s) for s in set(b["stimuli"])})
        basis = "uniform (no fit yet)" if b["fit_id"] is None else f"fit {b['fit_id']}"
        print(f"  block {b['block']} of {b['participant']} at {b['issued_at']}: "
              f"{len(b['stimuli'])} trials from {basis}, {len(set(b['stimuli']))} stimuli "
              f"({counts[0]}-{counts[-1]} times each), {1000 * b['seconds']:.0f} ms")
