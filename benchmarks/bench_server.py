"""Throughput and upload latency of the study server: 20 simulated participants x 240
ratings uploading at once to a real ``cgvq-study serve`` (uvicorn, SQLite WAL with
synchronous=FULL) on 127.0.0.1, through the app's own upload client.

Two loads: ``burst`` (every participant rates as fast as it can: the uploader batches what
accumulated; this is the server's throughput) and ``paced`` (each participant rates every
``--pace`` seconds, so nearly every upload carries one rating: the latency a participant's
app sees). Prints ratings/s and the p50/p99 latency of upload requests (POST entries).

    .venv/bin/python benchmarks/bench_server.py [--raters 20] [--pace 0.25] [--loads burst,paced]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import threading
import time
from pathlib import Path
from typing import ClassVar

import numpy as np

from session_store.invite import read_invites
from stimuli_manifests import fill_checksums, load_manifest, parse_manifest, save_manifest
from study_app.remote import ServerClient
from study_app.simulate import SimulationOptions, UploadOptions, run_simulation
from study_server.child import ServeProcess
from study_server.operations import invite

REPO = Path(__file__).resolve().parents[1]


def make_study(folder: Path) -> Path:
    """80 stimuli (20 references as hidden references + 60 conditions) x 3 repetitions = 240
    trials; the 'videos' are small random files (the server never decodes)."""
    rng = np.random.default_rng(0)
    (folder / "videos").mkdir(parents=True)
    refs, conds = [], []
    for r in range(20):
        (folder / "videos" / f"r{r}.mkv").write_bytes(rng.bytes(512))
        refs.append({"path": f"r{r}.mkv", "scene": f"scene{r}"})
        for c in range(3):
            (folder / "videos" / f"r{r}c{c}.mkv").write_bytes(rng.bytes(512))
            conds.append({"reference": f"SRC{r + 1:02d}", "method": "noise", "level": c + 1,
                          "path": f"r{r}c{c}.mkv"})
    m = parse_manifest({"study_id": "bench", "root": "videos", "references": refs,
                        "conditions": conds, "protocol": {"repetitions": 3}})
    save_manifest(m, folder / "manifest.json")
    save_manifest(fill_checksums(load_manifest(folder / "manifest.json")),
                  folder / "manifest.json")
    return folder


class TimedClient(ServerClient):
    latencies: ClassVar[list[float]] = []
    lock = threading.Lock()

    def json(self, method, path, payload=None):
        t0 = time.perf_counter()
        out = super().json(method, path, payload)
        if path.endswith("/entries"):
            with self.lock:
                self.latencies.append(time.perf_counter() - t0)
        return out


def serve(study: Path) -> ServeProcess:
    env = {**os.environ, "PYTHONPATH": str(REPO), "CGVQ_ADMIN_TOKEN": "bench-admin-token-0123"}
    return ServeProcess(study, ["--stats-every", "30", "--rate", "1000", "--burst", "1000"],
                        env=env).start()


def run_load(name: str, raters: int, pace: float) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        study = make_study(Path(tmp) / "study")
        invite(study, raters, Path(tmp) / "invites.csv")
        tokens = {i.participant: i.token for i in read_invites(Path(tmp) / "invites.csv")}
        server = serve(study)
        url = server.url
        TimedClient.latencies = []
        try:
            t0 = time.perf_counter()
            result = run_simulation(
                study / "manifest.json", Path(tmp) / "local",
                SimulationOptions(raters=raters, seed=0), progress=False,
                upload=UploadOptions(url, tokens, pace_s=pace, client_factory=TimedClient))
            seconds = time.perf_counter() - t0
        finally:
            server.stop()
        arrived = all(s.all_arrived for s in result.upload.values())
        lat = np.array(TimedClient.latencies) * 1000
        n = raters * 240
        print(f"{name:6s}: {raters} x 240 = {n} ratings in {seconds:.1f} s = "
              f"{n / seconds:.0f} ratings/s; {len(lat)} uploads ({n / len(lat):.1f} ratings "
              f"each), latency p50 {np.percentile(lat, 50):.1f} ms, p99 "
              f"{np.percentile(lat, 99):.1f} ms, max {lat.max():.1f} ms; everything arrived: "
              f"{arrived}", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--raters", type=int, default=20)
    parser.add_argument("--pace", type=float, default=0.25,
                        help="seconds between two ratings of a participant (paced load)")
    parser.add_argument("--loads", default="burst,paced")
    args = parser.parse_args()
    print(f"machine: {os.cpu_count()} cores; load average "
          f"{', '.join(f'{x:.1f}' for x in os.getloadavg())}")
    for load in args.loads.split(","):
        run_load(load, args.raters, 0.0 if load == "burst" else args.pace)


if __name__ == "__main__":
    main()
