"""``cgvqm batch --ray`` and ``cgvqm calibrate --ray`` on a small local Ray cluster: the same
numbers as a local run, resume, a killed worker, a unit that always fails, and the one-line
message when Ray is not installed. Each check compares with a local run of the same study."""

from __future__ import annotations

import csv
import importlib.util
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cgvqm_core.cli import main
from stimuli_manifests import (
    StimuliError,
    fill_checksums,
    load_manifest,
    save_manifest,
    write_video,
)

from .conftest import distort, smooth_video

HAVE_RAY = importlib.util.find_spec("ray") is not None
needs_ray = pytest.mark.skipif(not HAVE_RAY, reason="ray is not installed (the [cluster] extra)")

REPO = Path(__file__).resolve().parents[2]
FPS = 8
N_REFS = 3
METRIC_ARGS = ["--metrics", "cgvqm-2,psnr", "--random-backbone", "0", "--weights", "uniform",
               "--pool", "max", "--pool", "mean"]
COMPARED = ("stimulus", "reference", "metric", "pooling", "score", "direction", "note",
            "backbone_sha256", "weights_sha256", "settings", "versions")


def _break_after_header(path: Path) -> None:
    """Overwrite bytes in the middle of the file until its header still gives every frame
    but decoding them fails."""
    from cgvqm_core.errors import CGVQMError
    from cgvqm_core.stream import open_input

    good = path.read_bytes()
    n = int(open_input(path).info.frame_count)
    for tenth in range(2, 9):
        bad = bytearray(good)
        at = len(good) * tenth // 10
        bad[at: at + 2000] = b"\xff" * 2000
        path.write_bytes(bytes(bad))
        try:
            src = open_input(path)
            if int(src.info.frame_count) == n:
                sum(1 for _ in src.frames())
        except CGVQMError:
            continue  # the header is broken too: the probe would find it
        except StimuliError:  # the frames do not decode: what is wanted
            return
    raise AssertionError(f"{path}: no overwrite left the header readable and the frames not")


def make_study(root: Path, *, broken: str | None = None) -> Path:
    """N_REFS references x 2 noise levels (32x32, 8 frames); ``broken``: a test video's file
    name whose frames no decoder reads, behind a readable header (checksummed as it is), so
    the batch's probe passes and its unit fails where it runs."""
    videos = root / "videos"
    refs, conds, dmos = [], [], []
    for r in range(N_REFS):
        ref = smooth_video(r, 8, 32, 32)
        write_video(videos / f"src{r}.mkv", ref, FPS)
        refs.append({"path": f"src{r}.mkv", "scene": f"scene{r}"})
        for lv in (1, 2):
            name = f"src{r}_d{lv}.mkv"
            write_video(videos / name, distort(ref, 10 * r + lv, sigma=8.0 * lv), FPS)
            if name == broken:
                _break_after_header(videos / name)
            conds.append({"reference": f"SRC{r + 1:02d}", "path": name, "method": "noise",
                          "level": lv})
            dmos.append(f"SRC{r + 1:02d}_HRC{lv:02d},{90 - 20 * lv - r}")
    path = root / "manifest.json"
    path.write_text(json.dumps({"format": "cgvq-manifest/1", "study_id": "ray", "root": "videos",
                                "references": refs, "conditions": conds}))
    save_manifest(fill_checksums(load_manifest(path)), path)
    (root / "dmos.csv").write_text("stimulus,dmos\n" + "\n".join(dmos) + "\n")
    return path


def scores(path: Path) -> dict[str, tuple[str, ...]]:
    """Each row's compared columns by resume key (``seconds`` is a timing, not a number)."""
    with path.open(newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    out = {r["key"]: tuple(r[c] for c in COMPARED) for r in rows}
    assert len(out) == len(rows), "a row was written twice"
    return out


def batch(manifest: Path, out: Path, *extra: str) -> int:
    return main(["batch", "--manifest", str(manifest), "--out", str(out), *METRIC_ARGS,
                 *extra])


@pytest.fixture(scope="module")
def study(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_study(tmp_path_factory.mktemp("study"))


@pytest.fixture(scope="module")
def module_env(tmp_path_factory: pytest.TempPathFactory):
    """Environment of this process and of the Ray workers it starts (set before ray.init)."""
    tmp = tmp_path_factory.mktemp("ray-env")
    faults = tmp / "faults.json"
    faults.write_text("{}")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("RAY_USAGE_STATS_ENABLED", "0")
        mp.setenv("CGVQM_OFFLINE", "1")
        mp.setenv("CGVQM_CACHE", str(tmp / "cgvqm-cache"))
        mp.setenv("TORCH_HOME", str(tmp / "torch-home"))
        mp.setenv("CGVQM_TEST_FAULTS", str(faults))
        mp.setenv("PYTHONPATH", os.pathsep.join(
            [str(REPO), *filter(None, [os.environ.get("PYTHONPATH")])]))
        yield faults


@pytest.fixture(scope="module")
def local_scores(study: Path, module_env: Path, tmp_path_factory: pytest.TempPathFactory
                 ) -> Path:
    """The reference: a local run (one torch thread, as the Ray tasks below use)."""
    out = tmp_path_factory.mktemp("local") / "scores.csv"
    assert batch(study, out) == 0
    return out


@pytest.fixture(scope="module")
def cluster(module_env: Path):
    import ray

    shm = shutil.disk_usage("/dev/shm").free if Path("/dev/shm").is_dir() else 0
    store = int(min(500e6, max(100e6, shm // 4)))
    ray.init(address="local", num_cpus=2, include_dashboard=False, object_store_memory=store,
             logging_level="WARNING")
    try:
        yield module_env
    finally:
        ray.shutdown()


def _settings():
    from cgvqm_core.ray_options import RaySettings

    return RaySettings(cpus_per_unit=1)


# about 12 s: CI runs it after `make test` (.ci/run), as `make test-slow` does
@pytest.mark.slow
@needs_ray
def test_ray_batch_gives_the_local_numbers(study, local_scores, cluster, tmp_path, capsys):
    out = tmp_path / "ray.csv"
    assert batch(study, out, "--ray", "--ray-cpus-per-unit", "1") == 0
    capsys.readouterr()
    expected = scores(local_scores)
    assert len(expected) == N_REFS * 2 * 3  # tests x (cgvqm max, cgvqm mean, psnr)
    assert scores(out) == expected  # bitwise: same device, precision and thread count


@pytest.mark.slow  # a Ray cluster (about 13 s here, its start 7 s): CI runs it after `make test`
@needs_ray
def test_ray_resume_submits_only_missing_units(study, local_scores, cluster, tmp_path):
    from cgvqm_core import distributed
    from cgvqm_core.metrics import MetricOptions

    out = tmp_path / "partial.csv"
    with local_scores.open(newline="") as src, out.open("w", newline="") as dst:
        rows = list(csv.reader(src))
        ref_col = rows[0].index("reference")
        csv.writer(dst).writerows([r for r in rows if r[ref_col] != "SRC02"])
    options = MetricOptions(random_backbone=0, weights="uniform", pools=("max", "mean"))
    run = {"on_conversion": "error", "progress": False}  # as the CLI without --allow-convert
    s = distributed.score_manifest(study, out, ["cgvqm-2", "psnr"], options, _settings(), **run)
    assert (s.units, s.submitted, s.failed) == (N_REFS, 1, [])
    assert (s.scored, s.skipped) == (2, 4)
    assert scores(out) == scores(local_scores)
    again = distributed.score_manifest(study, out, ["cgvqm-2", "psnr"], options, _settings(),
                                       **run)
    assert (again.submitted, again.rows) == (0, 0)


@pytest.mark.slow  # a Ray cluster (about 4 s here, its start 7 s): CI runs it after `make test`
@needs_ray
def test_a_killed_worker_costs_only_its_unit(study, local_scores, cluster, tmp_path, capsys):
    marker = tmp_path / "killed-once"
    cluster.write_text(json.dumps({"SRC02": str(marker)}))
    try:
        out = tmp_path / "ray.csv"
        rc = batch(study, out, "--ray", "--ray-retries", "2")
    finally:
        cluster.write_text("{}")
    _, err = capsys.readouterr()
    assert rc == 0, err
    with pytest.raises(ProcessLookupError):  # the first try at SRC02 killed its worker
        os.kill(int(marker.read_text()), 0)
    assert scores(out) == scores(local_scores)


@pytest.mark.slow  # a Ray cluster (about 8 s here, its start 7 s): CI runs it after `make test`
@needs_ray
def test_a_unit_failing_every_time_is_named_and_the_others_land(local_scores, cluster,
                                                                tmp_path, capsys):
    manifest = make_study(tmp_path, broken="src1_d2.mkv")  # SRC02's second test
    out = tmp_path / "ray.csv"
    rc = batch(manifest, out, "--ray")
    _, err = capsys.readouterr()
    assert rc == 2
    lines = [ln for ln in err.splitlines() if ln.startswith("cgvqm: error:")]
    assert len(lines) == 1 and "SRC02" in lines[0] and "1 of 3" in lines[0], err
    expected = {k: v for k, v in scores(local_scores).items() if v[1] != "SRC02"}
    assert scores(out) == expected  # the same files, so the same keys and numbers


def _no_ray_site(tmp_path: Path) -> Path:
    """A sitecustomize that makes ``import ray`` fail as where it is not installed."""
    site = tmp_path / "site"
    site.mkdir()
    (site / "sitecustomize.py").write_text(
        "import importlib.abc, sys\n"
        "class _NoRay(importlib.abc.MetaPathFinder):\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name.split('.')[0] == 'ray':\n"
        "            raise ModuleNotFoundError(f'No module named {name!r}', name=name)\n"
        "sys.meta_path.insert(0, _NoRay())\n")
    return site


@pytest.mark.slow  # about 11 s here: CI runs it after `make test` (.ci/run)
def test_ray_without_the_extra_is_one_line(tmp_path):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(_no_ray_site(tmp_path)), str(REPO)]),
           "CGVQM_OFFLINE": "1"}
    for args in (["batch", "--manifest", "m.json", "--out", "s.csv", "--ray"],
                 ["calibrate", "--dataset", "d=m.json:d.csv", "--out", "w.json", "--ray",
                  "auto"]):
        p = subprocess.run([sys.executable, "-m", "cgvqm_core", *args], cwd=tmp_path, env=env,
                           capture_output=True, text=True, timeout=120)
        assert p.returncode == 2, p.stderr
        assert p.stderr.count("\n") == 1 and "[cluster]" in p.stderr, p.stderr
        assert "Traceback" not in p.stderr


def test_bad_ray_options_are_one_line(capsys, tmp_path):
    for extra, words in ((["--ray", "--ray-cpus-per-unit", "0"], "at least 1"),
                         (["--ray", "--device", "cuda:1"], "--device cuda"),
                         (["--ray-gpus-per-unit", "1"], "needs --ray"),
                         # without --ray they would be ignored, even invalid values
                         (["--ray-cpus-per-unit", "4"], "--ray-cpus-per-unit needs --ray"),
                         (["--ray-retries", "-3"], "--ray-retries needs --ray"),
                         (["--ray", "--threads", "2"], "each task runs --ray-cpus-per-unit")):
        assert main(["batch", "--manifest", "m.json", "--out", str(tmp_path / "s.csv"),
                     *extra]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and words in err, err


@pytest.mark.slow  # a Ray cluster (about 1 s here, its start 7 s): CI runs it after `make test`
@needs_ray
def test_a_request_no_node_meets_is_refused_at_once(study, cluster, tmp_path, capsys):
    assert batch(study, tmp_path / "s.csv", "--ray", "--ray-cpus-per-unit", "3") == 2
    err = capsys.readouterr().err
    assert err.count("cgvqm: error:") == 1 and "no node of the cluster has 3 CPU(s)" in err


@pytest.mark.slow  # a Ray cluster (about 9 s here, its start 7 s): CI runs it after `make test`
@needs_ray
def test_calibrate_ray_fills_the_same_cache(study, cluster, tmp_path, capsys):
    def features(cache: Path, *extra: str) -> dict[str, np.ndarray]:
        rc = main(["calibrate", "--dataset", f"s={study}:{study.parent / 'dmos.csv'}",
                   "--random-backbone", "0", "--cache", str(cache), "--features-only",
                   "--quiet", *extra])
        assert rc == 0, capsys.readouterr().err
        return {str(p.relative_to(cache)): np.load(p) for p in cache.rglob("*.npy")}

    local = features(tmp_path / "local")
    remote = features(tmp_path / "ray", "--ray")
    assert len(local) == N_REFS * 2 and local.keys() == remote.keys()
    for name, m in local.items():
        assert np.array_equal(m, remote[name]), name
    (index,) = (tmp_path / "ray").rglob("index.json")
    entries = json.loads(index.read_text())["entries"]
    assert {e["file"] for e in entries.values()} == {Path(n).name for n in local}
