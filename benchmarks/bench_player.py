"""Presentation timing of the real player on a virtual 60 Hz display (Xvfb + Mesa llvmpipe).

For 1024x1024 stimuli at 30 and 60 fps it runs ``cgvq-study run``'s app on a private Xvfb,
injects SDL key events (Space every 2 s for a 10 s viewing, then Enter, a rating and quit)
and reads the presentation log from the session file. Prints frames presented vs expected,
dropped frames, blank duration error, switch latency and the p99 flip interval.
Target: zero dropped frames, blank within one refresh of 0.5 s.

    .venv/bin/python benchmarks/bench_player.py [--seconds 10] [--fps 30 60]
"""

from __future__ import annotations

import argparse
import itertools
import logging
import os
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))


def make_study(folder: Path, fps: int, size: int, seconds: float) -> Path:
    from stimuli_manifests import (
        fill_checksums,
        load_manifest,
        parse_manifest,
        save_manifest,
        write_video,
    )

    n = round(fps * seconds)
    yy, xx = np.mgrid[0:size, 0:size]
    ref = np.empty((n, size, size, 3), dtype=np.uint8)
    for t in range(n):
        for c in range(3):
            ref[t, :, :, c] = ((xx + 3 * t * (c + 1)) ^ (yy + 5 * t)) & 0xFF
    rng = np.random.default_rng(0)
    test = np.clip(ref.astype(np.int16) + rng.integers(-20, 21, ref.shape), 0, 255)
    write_video(folder / "videos" / "ref.mkv", ref, fps)
    write_video(folder / "videos" / "test.mkv", test.astype(np.uint8), fps)
    manifest = parse_manifest({
        "study_id": f"bench-{fps}", "root": "videos",
        "protocol": {"repetitions": 1, "blank_seconds": 0.5},
        "display": {"min_width": size, "min_height": size, "min_refresh_hz": 59},
        "references": [{"path": "ref.mkv", "width": size, "height": size}],
        "conditions": [{"reference": "SRC01", "path": "test.mkv", "method": "noise",
                        "level": 1}],
    })
    save_manifest(manifest, folder / "manifest.json")
    save_manifest(fill_checksums(load_manifest(folder / "manifest.json")),
                  folder / "manifest.json")
    return folder


class StateWatcher(logging.Handler):
    """Collects the app's ``state:`` debug lines."""

    def __init__(self) -> None:
        super().__init__(logging.DEBUG)
        self.states: list[str] = []
        self.times: dict[str, float] = {}  # first time each state was seen
        self.cond = threading.Condition()

    def emit(self, record: logging.LogRecord) -> None:
        msg = record.getMessage()
        if msg.startswith("state:"):
            with self.cond:
                self.times.setdefault(msg, time.perf_counter())
                self.states.append(msg)
                self.cond.notify_all()

    def wait(self, text: str, timeout: float = 120) -> None:
        with self.cond:
            ok = self.cond.wait_for(
                lambda: any(re.search(rf"state: {re.escape(text)}(\s|$)", s)
                            for s in self.states), timeout)
        if not ok:
            raise TimeoutError(f"player never reached {text!r}")
        with self.cond:
            self.states.clear()


def script(watch: StateWatcher, seconds: float, errors: list[BaseException]) -> None:
    import pygame

    def key(k: int) -> None:
        pygame.event.post(pygame.event.Event(pygame.KEYDOWN, key=k, mod=0, unicode="",
                                             scancode=0))

    try:
        watch.wait("viewing trial=0")
        t_end = time.monotonic() + seconds
        time.sleep(1.0)
        while time.monotonic() < t_end - 1.0:
            key(pygame.K_SPACE)
            time.sleep(2.0)
        time.sleep(max(0.0, t_end - time.monotonic()))
        for _ in range(100):  # Enter opens the rating once a loop was presented (not in a blank)
            key(pygame.K_RETURN)
            try:
                watch.wait("rating", timeout=0.3)
                break
            except TimeoutError:
                continue
        else:
            raise TimeoutError("the rating screen never opened")
        key(pygame.K_RIGHT)
        time.sleep(0.1)
        key(pygame.K_RETURN)
        watch.wait("viewing trial=1")
        key(pygame.K_p)
        watch.wait("pause")
        key(pygame.K_q)
        watch.wait("confirm-quit")  # quitting asks first
        key(pygame.K_y)
    except BaseException as exc:  # reported by the main thread
        errors.append(exc)


def run_one(fps: int, seconds: float, size: int, workdir: Path, *, harden: bool = True
            ) -> dict:
    from flip_probe import Canary, FlipProbe

    from session_store import SessionStore
    from session_store.study_folder import load_study
    from study_app import realtime
    from study_app.app import RunOptions, run_study

    study = load_study(make_study(workdir / f"study{fps}", fps, size, 3.0))
    probe = FlipProbe().install()
    canary = Canary(workdir)
    saved = realtime.presentation_guard, realtime.raise_priority
    if not harden:  # the player as it was before the hardening, for comparison
        realtime.presentation_guard = realtime.unguarded
        realtime.raise_priority = lambda: "not attempted (benchmark: --no-hardening)"
    watch = StateWatcher()
    logging.getLogger("study_app").addHandler(watch)
    logging.getLogger("study_app").setLevel(logging.DEBUG)
    errors: list[BaseException] = []
    thread = threading.Thread(target=script, args=(watch, seconds, errors), daemon=True)
    thread.start()
    try:
        run_study(study, RunOptions(participant="bench", practice=0, max_dropped_frames=-1,
                                    skip_preflight=True, seed=1))
    finally:
        logging.getLogger("study_app").removeHandler(watch)
        probe.uninstall()
        canary.stop()
        realtime.presentation_guard, realtime.raise_priority = saved
    thread.join(timeout=5)
    if errors:
        raise errors[0]
    with SessionStore.open(study.session_path("bench")) as store:
        log0 = next(p for p in store.presentations() if p["trial"] == 0)
        display = store.info.display
    period_ms = 1000.0 / display["refresh_hz"]
    t0 = next(t for m, t in watch.times.items() if m.startswith("state: viewing trial=0"))
    t1 = next(t for m, t in watch.times.items() if m.startswith("state: rating"))
    flips = [r for r in probe.records if t0 <= r.t <= t1]
    return {"fps": fps, "display": display, "log": log0, "period_ms": period_ms,
            "flips": flips, "canary": canary}


def stall_lines(res: dict) -> list[tuple[float, str]]:
    """(interval in periods, cause) of every stall of the viewing phase."""
    from flip_probe import attribute, stalls

    period = res["period_ms"] / 1000
    out = []
    for iv, rec in stalls(res["flips"], period):
        cause = attribute(iv, rec, period)
        held = res["canary"].overlap(rec.t - iv, rec.t)
        if held > 0.5 * (iv - period):
            cause = f"machine (a sleeping process was held up {1000 * held:.0f} ms too)"
        out.append((iv / period, cause))
    return out


def report(res: dict) -> bool:
    log, period = res["log"], res["period_ms"]
    expected = log["viewing_ms"] / period + 1
    blanks = np.array(log["blank_durations_ms"])
    lat = np.array(log["switch_latencies_ms"])
    print(f"\n{res['fps']} fps stimuli, {res['display']['window'][0]}x"
          f"{res['display']['window'][1]} window, vsync={res['display']['vsync']}, "
          f"{res['display']['refresh_hz']:.2f} Hz ({res['display']['refresh_source']})")
    print(f"  viewing time            {log['viewing_ms'] / 1000:.2f} s")
    print(f"  frames presented        {log['frames_presented']} (expected {expected:.0f})")
    print(f"  dropped frames          {log['dropped_frames']}")
    print(f"  max / p99 flip interval {log['max_flip_interval_ms']:.2f} / "
          f"{log['p99_flip_interval_ms']:.2f} ms (nominal {period:.2f})")
    print(f"  CPU per flip (process)  {log['cpu_ms_per_flip']:.2f} ms "
          f"(all threads; {100 * log['cpu_ms_per_flip'] / period:.0f}% of one core at "
          f"{1000 / period:.0f} Hz)")
    if blanks.size:
        err = blanks - 500.0
        print(f"  blank duration error    mean {err.mean():+.2f} ms, max |err| "
              f"{np.abs(err).max():.2f} ms ({np.abs(err).max() / period:.2f} refreshes) "
              f"over {blanks.size} blanks")
    if lat.size:
        print(f"  switch latency          mean {lat.mean():.1f} ms, max {lat.max():.1f} ms "
              f"(blank + {(lat.max() - 500) / period:.2f} refreshes at most)")
    for periods, cause in stall_lines(res):
        print(f"  stall                   {periods:.1f} refreshes: {cause}")
    print(f"  scheduling              {res['display'].get('priority', 'unknown')}")
    print(f"  hypervisor steal        {res['canary'].steal * 10} ms during the run; canary "
          f"late (> 6 ms) {len(res['canary'].gaps)} times")
    ok = log["dropped_frames"] == 0 and (not blanks.size or np.abs(blanks - 500).max() <= period)
    print(f"  target (0 dropped, blank within 1 refresh): {'MET' if ok else 'NOT MET'}")
    return bool(ok)


def print_histogram(all_stalls: list[tuple[float, str]]) -> None:
    """Stalls by length (in refresh periods) and by cause."""
    edges = [1.5, 2.5, 3.5, 6.5, float("inf")]
    names = ["1.5-2.5", "2.5-3.5", "3.5-6.5", ">6.5"]
    counts = [sum(lo < p <= hi for p, _ in all_stalls) for lo, hi in itertools.pairwise(edges)]
    print(f"  stalls: {len(all_stalls)} in all; by length (refreshes) "
          + ", ".join(f"{n}: {c}" for n, c in zip(names, counts, strict=True)))
    causes: dict[str, int] = {}
    for _, cause in all_stalls:
        causes[cause] = causes.get(cause, 0) + 1
    if causes:
        print("  by cause: " + ", ".join(f"{c}: {n}" for c, n in
                                         sorted(causes.items(), key=lambda kv: -kv[1])))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="viewing time per condition")
    ap.add_argument("--fps", type=int, nargs="+", default=[30, 60])
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--runs", type=int, default=1,
                    help="repeat each frame rate N times (timing on shared machines varies)")
    ap.add_argument("--screen", default="1920x1200", help="Xvfb screen size")
    ap.add_argument("--use-display", action="store_true",
                    help="use $DISPLAY instead of starting a private Xvfb")
    ap.add_argument("--no-hardening", action="store_true",
                    help="run the player without its presentation hardening (no GC pause "
                         "control, no priority change), to compare")
    args = ap.parse_args()
    xvfb = None
    if not args.use_display:
        if shutil.which("Xvfb") is None:
            print("Xvfb is not installed; run with --use-display on a real display")
            return 2
        n = next(i for i in range(150, 250) if not Path(f"/tmp/.X{i}-lock").exists())
        xvfb = subprocess.Popen(["Xvfb", f":{n}", "-screen", "0", f"{args.screen}x24",
                                 "-nolisten", "tcp"], stderr=subprocess.DEVNULL)
        while not Path(f"/tmp/.X11-unix/X{n}").exists():
            time.sleep(0.05)
        os.environ["DISPLAY"] = f":{n}"
        os.environ["SDL_VIDEODRIVER"] = "x11"
    try:
        met: dict[int, list[bool]] = {fps: [] for fps in args.fps}
        drops: dict[int, list[int]] = {fps: [] for fps in args.fps}
        all_stalls: list[tuple[float, str]] = []
        for _ in range(args.runs):
            with tempfile.TemporaryDirectory() as tmp:
                for fps in args.fps:
                    res = run_one(fps, args.seconds, args.size, Path(tmp),
                                  harden=not args.no_hardening)
                    met[fps].append(report(res))
                    drops[fps].append(res["log"]["dropped_frames"])
                    all_stalls += stall_lines(res)
        print(f"\nover {args.runs} run(s), hardening "
              f"{'off' if args.no_hardening else 'on'} (load average now "
              f"{os.getloadavg()[0]:.1f}):")
        for fps in args.fps:
            print(f"  {fps} fps: target met in {sum(met[fps])} of {args.runs} runs, "
                  f"dropped frames per run {drops[fps]}")
        print_histogram(all_stalls)
    finally:
        if xvfb is not None:
            xvfb.terminate()
    return 0


if __name__ == "__main__":
    sys.exit(main())
