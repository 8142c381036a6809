"""CPU a text screen costs while the participant reads it (or leaves it open): the player's
preview intro screen on a private Xvfb (Mesa llvmpipe, software rendering), sampled from
/proc for a few seconds. Target: a few percent of a core (the screen is drawn again only on
input, and twice a second otherwise; it used to be drawn every refresh, 40-47 %).

    .venv/bin/python benchmarks/bench_idle_screen.py [--seconds 5]
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "benchmarks"))


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process so far."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=5.0, help="sampling time")
    args = ap.parse_args()
    if shutil.which("Xvfb") is None:
        print("Xvfb is not installed")
        return 2
    from bench_player import make_study

    n = next(i for i in range(150, 250) if not Path(f"/tmp/.X{i}-lock").exists())
    xvfb = subprocess.Popen(["Xvfb", f":{n}", "-screen", "0", "1280x1024x24", "-nolisten",
                             "tcp"], stderr=subprocess.DEVNULL)
    env = {**os.environ, "DISPLAY": f":{n}", "SDL_VIDEODRIVER": "x11",
           "SDL_AUDIODRIVER": "dummy"}
    try:
        while not Path(f"/tmp/.X11-unix/X{n}").exists():
            time.sleep(0.05)
        with tempfile.TemporaryDirectory() as tmp:
            study = make_study(Path(tmp) / "study", 30, 128, 1.0)
            app = subprocess.Popen([sys.executable, "-m", "cgvq_cli.study_cli", "-v",
                                    "preview", str(study), "--windowed", "--window-size",
                                    "1024x768"], env=env, stdout=subprocess.DEVNULL,
                                   stderr=subprocess.PIPE, text=True)
            try:
                for line in app.stderr:  # the intro screen takes input from here on
                    if "state: preview-intro" in line:
                        break
                else:
                    print("the preview did not reach its intro screen")
                    return 1
                time.sleep(1.0)
                t0, c0 = time.monotonic(), cpu_seconds(app.pid)
                time.sleep(args.seconds)
                used = (cpu_seconds(app.pid) - c0) / (time.monotonic() - t0)
            finally:
                app.kill()
                app.wait()
        print(f"preview intro screen, idle for {args.seconds:g} s: {100 * used:.1f} % of "
              f"one core (load average {os.getloadavg()[0]:.1f})")
    finally:
        xvfb.terminate()
    return 0


if __name__ == "__main__":
    sys.exit(main())
