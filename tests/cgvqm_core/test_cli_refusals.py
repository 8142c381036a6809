"""Issue 22, item 3: ``cgvqm`` refuses out-of-range counts, seeds and frame rates, malformed
weights files, and (with --strict) a frame-count mismatch, in one line on stderr with exit 2;
without --strict the warning says how many frames the resampler invented."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from cgvqm_core import CGVQMError
from cgvqm_core.cli import main
from cgvqm_core.hub import MAX_SEED, check_seed
from cgvqm_core.weights import load_weights
from stimuli_manifests import write_video

FPS = 8
N_REF = 8  # the reference's frames; tests of a mismatch have half of them
HW = 32


def _run(capsys: pytest.CaptureFixture[str], *args: object) -> tuple[int, str, str]:
    rc = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return rc, out, err


def _refused(rc: int, err: str, *names: str) -> str:
    """The one stderr line of a refusal, after checking exit code 2 and its shape."""
    assert rc == 2, err
    assert "Traceback" not in err
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("cgvqm: error: ")
    for name in names:
        assert name in lines[0], (name, lines[0])
    return lines[0]


@pytest.fixture
def npy_pair(tmp_path: Path, vids) -> tuple[Path, Path]:
    ref = vids.smooth(1, N_REF, HW, HW)
    r, t = tmp_path / "r.npy", tmp_path / "t.npy"
    np.save(r, ref)
    np.save(t, vids.distort(ref, 2))
    return r, t


def _score_args(pair: tuple[Path, Path], *extra: object) -> list[object]:
    r, t = pair
    opts = list(extra)
    if "--random-backbone" not in opts:
        opts += ["--random-backbone", 0]
    if "--fps" not in opts:
        opts += ["--fps", FPS]
    return ["score", "--ref", r, "--test", t, "--weights", "uniform", *opts]


@pytest.mark.parametrize(("option", "value", "names"), [
    ("--batch-size", "0", ["--batch-size", "at least 1", "got 0"]),
    ("--batch-size", "-3", ["--batch-size", "got -3"]),
    ("--patch-scale", "0", ["--patch-scale", "got 0"]),
    ("--threads", "0", ["--threads", "got 0"]),
    ("--random-backbone", "-1", ["--random-backbone", f"from 0 to {MAX_SEED}", "got -1"]),
    ("--random-backbone", str(MAX_SEED + 1), [f"got {MAX_SEED + 1}"]),
    ("--fps", "inf", ["--fps", "finite", "above 0", "got inf"]),
    ("--fps", "nan", ["--fps", "got nan"]),
    ("--fps", "0", ["--fps", "got 0.0"]),
    ("--fps", "-5", ["--fps", "got -5.0"]),
])
def test_score_refuses_out_of_range_options(capsys, npy_pair, option, value, names):
    rc, out, err = _run(capsys, *_score_args(npy_pair, option, value))
    _refused(rc, err, *names)
    assert out == ""


@pytest.mark.parametrize(("option", "value"), [
    ("--batch-size", "0"), ("--group-size", "0"), ("--group-size", "-1"), ("--threads", "0"),
    ("--patch-scale", "0"), ("--random-backbone", "-1"),
])
def test_batch_refuses_out_of_range_options(capsys, tmp_path, vids, option, value):
    manifest = _manifest(tmp_path, vids, test_frames=N_REF)
    rc, _, err = _run(capsys, "batch", "--manifest", manifest, "--out", tmp_path / "s.csv",
                      option, value)
    _refused(rc, err, option, f"got {value}")
    assert not (tmp_path / "s.csv").exists()


def test_seed_range_is_what_torch_takes_without_wrapping():
    """torch.manual_seed(-1) silently means seed 2**64-1: the reason negatives are refused."""
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(-1)
        assert torch.initial_seed() == MAX_SEED
    assert check_seed(0) == 0 and check_seed(MAX_SEED) == MAX_SEED
    for bad in (-1, MAX_SEED + 1, 1.5, True):
        with pytest.raises(CGVQMError, match="from 0 to 18446744073709551615"):
            check_seed(bad)  # type: ignore[arg-type]


# -- malformed weights files ---------------------------------------------------------------

N2 = 131  # CGVQM-2's omega length


@pytest.mark.parametrize(("omega", "alpha", "names"), [
    ([[1 / N2] * N2], 2.0, ["omega must be a flat JSON array", "omega[0] is a nested array"]),
    ([[1 / N2]] * N2, 2.0, ["omega[0] is a nested array"]),
    ([[[0.1]]] * N2, 2.0, ["omega[0] is a nested array"]),
    (["0.1"] * N2, 2.0, ['omega[0] is a string ("0.1"), not a number']),
    ("abc", 2.0, ['not a string ("abc")']),
    ({"a": 1}, 2.0, ["not an object"]),
    ([0.1] * 10, 2.0, ["omega has 10 entries", "CGVQM-2 needs 131"]),
    ([0.1] * 3 + [float("nan")] + [0.1] * (N2 - 4), 2.0, ["omega[3] is NaN", "finite"]),
    ([0.1] * (N2 - 1) + [1e300], 2.0, [f"omega[{N2 - 1}] is 1e+300", "float32"]),
    ([True] * N2, 2.0, ["omega[0] is a boolean"]),
    ([0.1] * (N2 - 1) + [None], 2.0, [f"omega[{N2 - 1}] is null"]),
    ([0.1] * N2, "2", ['alpha is a string ("2")']),
    ([0.1] * N2, [2.0], ["alpha is an array"]),
])
def test_malformed_weights_json_is_refused_by_every_loader(capsys, tmp_path, npy_pair,
                                                          omega, alpha, names):
    path = tmp_path / "bad.json"
    path.write_text(json.dumps({"format": "cgvqm-weights/1", "variant": "cgvqm-2",
                                "alpha": alpha, "omega": omega}))
    with pytest.raises(CGVQMError) as info:
        load_weights(path)
    for name in names:
        assert name in str(info.value)
    rc, out, err = _run(capsys, "weights", "info", path)
    assert out == ""
    _refused(rc, err, str(path), *names)
    rc, _, err = _run(capsys, *_score_args(npy_pair, "--weights", path))
    _refused(rc, err, *names)


def test_well_formed_weights_json_still_loads(capsys, tmp_path):
    path = tmp_path / "ok.json"
    path.write_text(json.dumps({"format": "cgvqm-weights/1", "alpha": 2,
                                "omega": [1] + [0.5] * (N2 - 1)}))
    rc, out, err = _run(capsys, "weights", "info", path)
    assert rc == 0, err
    doc = json.loads(out)
    assert doc["n_channels"] == N2 and doc["alpha"] == 2.0


# -- frame-count mismatch: --strict refuses, otherwise the warning counts ------------------

def _videos(tmp_path: Path, vids, test_frames: int) -> tuple[Path, Path]:
    ref = vids.smooth(3, N_REF, HW, HW)
    test = vids.distort(vids.smooth(3, test_frames, HW, HW), 4)
    r = write_video(tmp_path / "videos" / "ref.mkv", ref, FPS)
    t = write_video(tmp_path / "videos" / "test.mkv", test, FPS)
    return Path(r), Path(t)


def _manifest(tmp_path: Path, vids, test_frames: int) -> Path:
    _videos(tmp_path, vids, test_frames)
    doc = {"format": "cgvq-manifest/1", "study_id": "t", "root": "videos",
           "references": [{"path": "ref.mkv"}],
           "conditions": [{"reference": "SRC01", "path": "test.mkv", "method": "noise",
                           "level": 1}]}
    path = tmp_path / "manifest.json"
    path.write_text(json.dumps(doc))
    return path


@pytest.mark.parametrize("test_frames", [N_REF // 2, N_REF - 1])
def test_score_warns_how_many_frames_were_invented(capsys, tmp_path, vids, test_frames):
    r, t = _videos(tmp_path, vids, test_frames)
    invented = N_REF - test_frames  # nearest resampling up: every test frame used once
    rc, out, err = _run(capsys, "score", "--ref", r, "--test", t, "--random-backbone", 0,
                        "--weights", "uniform")
    assert rc == 0, err
    (line,) = [x for x in err.splitlines() if "frames, reference" in x]
    assert (f"test has {test_frames} frames, reference {N_REF}: {invented} "
            f"frame{'s were' if invented > 1 else ' was'} invented by repeating test "
            "frames") in line
    assert "no interpolation" in line and "--strict" in line
    assert "cgvqm-2-uniform q =" in out


def test_score_warns_how_many_frames_were_dropped(capsys, tmp_path, vids):
    r, t = _videos(tmp_path, vids, 2 * N_REF)
    rc, _, err = _run(capsys, "score", "--ref", r, "--test", t, "--random-backbone", 0,
                      "--weights", "uniform")
    assert rc == 0, err
    assert f"test has {2 * N_REF} frames, reference {N_REF}: {N_REF} test frames were dropped" \
        in err
    # every reference frame i but the first meets test frame 2i: the whole clip is shifted,
    # not just its end (a -224 score read as "4 frames dropped")
    assert f"{N_REF - 1} of the {N_REF} reference frames are compared with a test frame " \
        "from another moment" in err


def test_frames_without_a_rate_take_the_videos_or_say_30_is_assumed(capsys, tmp_path, vids,
                                                                    npy_pair):
    """.npy arrays and PNG folders carry no frame rate: beside a video they take its rate
    (a 30 fps default made a 25 fps pair an error naming a rate nobody gave); two of them
    get 30 fps, said, since the rate sets CGVQM's clip length."""
    ref = write_video(tmp_path / "ref25.mkv", vids.smooth(1, N_REF, HW, HW), 25)
    args = ["score", "--ref", ref, "--test", npy_pair[1], "--random-backbone", 0,
            "--weights", "uniform", "--json"]
    rc, out, err = _run(capsys, *args)
    assert rc == 0, err
    assert "differs" not in err and json.loads(out)["provenance"]["test"]["fps"] == 25
    rc, out, err = _run(capsys, *[a for a in _score_args(npy_pair) if a != FPS and
                                  a != "--fps"], "--json")
    assert rc == 0, err
    assert "carry no frame rate: 30 fps assumed" in err
    assert json.loads(out)["provenance"]["test"]["fps"] == 30


def test_score_strict_refuses_a_frame_count_mismatch(capsys, tmp_path, vids):
    r, t = _videos(tmp_path, vids, N_REF // 2)
    rc, out, err = _run(capsys, "score", "--ref", r, "--test", t, "--random-backbone", 0,
                        "--weights", "uniform", "--strict")
    _refused(rc, err, f"test has {N_REF // 2} frames, reference {N_REF}", "--strict", str(t))
    assert out == ""
    # equal counts pass --strict
    same = write_video(tmp_path / "same.mkv", vids.smooth(4, N_REF, HW, HW), FPS)
    rc, out, err = _run(capsys, "score", "--ref", r, "--test", same, "--random-backbone", 0,
                        "--weights", "uniform", "--strict")
    assert rc == 0 and "cgvqm-2-uniform q =" in out, err


def test_batch_strict_refuses_and_plain_batch_warns(capsys, tmp_path, vids):
    half = N_REF // 2
    manifest = _manifest(tmp_path, vids, test_frames=half)
    out_csv = tmp_path / "scores.csv"
    rc, _, err = _run(capsys, "batch", "--manifest", manifest, "--out", out_csv,
                      "--metrics", "psnr", "--strict")
    _refused(rc, err, f"SRC01_HRC01 has {half} frames, its reference SRC01 {N_REF}",
             "--strict")
    assert not out_csv.exists() or out_csv.read_text().count("\n") <= 1
    rc, out, err = _run(capsys, "batch", "--manifest", manifest, "--out", out_csv,
                        "--metrics", "psnr")
    assert rc == 0 and "1 scored" in out, err
    assert (f"test has {half} frames, reference {N_REF}: {N_REF - half} frames were "
            "invented") in err


def test_help_documents_strict(capsys):
    for command in ("score", "batch"):
        with pytest.raises(SystemExit):
            main([command, "--help"])
        text = " ".join(capsys.readouterr().out.split())
        assert "--strict" in text and "refuse (exit 2) a test video whose frame count" in text


@pytest.mark.parametrize("extra", [[], ["--precision", "fp16"], ["--precision", "bf16"]])
def test_fast_stem_outside_fp16_on_cuda_is_refused(capsys, npy_pair, extra):
    """--fast-stem changes only fp16 on CUDA; anywhere else it would do nothing, silently."""
    rc, _, err = _run(capsys, *_score_args(npy_pair, "--fast-stem", *extra))
    _refused(rc, err, "--fast-stem", "fp16", "cuda")


# -- what the probe of every subcommand found (2026-11-27) ---------------------------------

def _no_warnings(err: str) -> str:
    """stderr without the warnings a random backbone and uniform weights print."""
    return "\n".join(x for x in err.splitlines() if not x.startswith("cgvqm: WARNING"))


def test_weights_of_another_variant_than_the_one_asked_for_are_refused(capsys, tmp_path,
                                                                      npy_pair):
    from cgvqm_core.weights import save_weights, uniform_weights

    five = save_weights(tmp_path / "five.json", uniform_weights("cgvqm-5"))
    args = [a for a in _score_args(npy_pair) if a != "uniform"]
    args[args.index("--weights") + 1:args.index("--weights") + 1] = [five]
    rc, out, err = _run(capsys, *args, "--variant", "cgvqm-2")
    _refused(rc, _no_warnings(err), "holds cgvqm-5", "cgvqm-2 was asked for")
    assert out == ""
    rc, out, err = _run(capsys, *args)  # no variant named: the file's is used
    assert rc == 0 and "cgvqm-5-five q =" in out, err  # named as its CSV rows are


def test_backbone_files_that_are_no_state_dict_are_named_so(capsys, tmp_path, npy_pair):
    empty, garbage = tmp_path / "empty.pth", tmp_path / "garbage.pth"
    empty.write_bytes(b"")
    garbage.write_bytes(np.random.default_rng(0).bytes(3000))
    for path, why in ((tmp_path, "is a folder"), (empty, "the backbone file is empty"),
                      (garbage, "not a PyTorch file of tensors only")):
        args = [a for a in _score_args(npy_pair) if a not in ("--random-backbone", 0)]
        rc, _, err = _run(capsys, *args, "--backbone", path)
        line = _refused(rc, _no_warnings(err), why)
        assert "weights_only" not in line  # torch's advice to run the file's code is dropped


def test_an_error_map_folder_that_is_a_file_and_a_bad_sha256_are_refused(capsys, tmp_path,
                                                                          npy_pair):
    (tmp_path / "maps.txt").write_text("not a folder")
    rc, _, err = _run(capsys, *_score_args(npy_pair, "--emap-png", tmp_path / "maps.txt"))
    _refused(rc, err, "--emap-png", "is a file")
    rc, _, err = _run(capsys, *_score_args(npy_pair, "--metric", "psnr",
                                           "--learned-sha256", "vgg16=zz"))
    _refused(rc, err, "--learned-sha256", "64 hexadecimal digits")


def test_a_manifest_without_test_videos_is_refused(capsys, tmp_path, vids):
    manifest = _manifest(tmp_path, vids, test_frames=N_REF)
    doc = json.loads(manifest.read_text())
    doc["conditions"] = []
    manifest.write_text(json.dumps(doc))
    rc, _, err = _run(capsys, "batch", "--manifest", manifest, "--out", tmp_path / "s.csv",
                      "--random-backbone", 0, "--weights", "uniform")
    _refused(rc, _no_warnings(err), "lists no test videos", "--include-references")
    assert not (tmp_path / "s.csv").exists()


def test_weights_verify_and_fetch_name_the_missing_file(capsys, tmp_path, monkeypatch):
    monkeypatch.setenv("CGVQM_CACHE", str(tmp_path / "cache"))
    rc, out, err = _run(capsys, "weights", "verify", tmp_path / "nope.pickle", tmp_path)
    line = _refused(rc, err, "2 file(s) missing", str(tmp_path / "nope.pickle"))
    assert "a folder, not a file" in out and "run `cgvqm weights fetch`" in line
    src = tmp_path / "src"
    src.mkdir()
    rc, _, err = _run(capsys, "weights", "fetch", "--from", src, "--backbone-file",
                      tmp_path / "nope.pth")
    _refused(rc, err, "--backbone-file", "no such file")
    assert not (tmp_path / "cache").exists()  # nothing copied before the refusal
    (src / "cgvqm-2.pickle").write_bytes(b"x")
    rc, _, err = _run(capsys, "weights", "fetch", "--from", src)
    _refused(rc, err, f"--from {src}: it holds no r3d_18-b3b3357e.pth", "--no-backbone")
    assert not (tmp_path / "cache").exists()


def test_score_takes_one_pooling(capsys, npy_pair):
    """`score --pool max --pool mean` wrote only the mean; batch is the one that takes both."""
    with pytest.raises(SystemExit) as exc:  # argparse's exit, as for any bad option
        main([str(a) for a in _score_args(npy_pair, "--pool", "max", "--pool", "mean")])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and err.count("\n") == 1, err
    assert err.startswith("cgvqm score: error: --pool given twice; score takes one")
