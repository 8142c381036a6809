"""Each metric declares the run options it reads (``MetricSpec.reads``), and the command line
refuses an option that none of the metrics asked for reads, instead of ignoring it."""

from __future__ import annotations

import ast
import inspect
from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest

from cgvqm_core.cli import main
from cgvqm_core.metrics import MetricOptions, entries, readers
from cgvqm_core.metrics.registry import _declaring_modules
from stimuli_manifests import write_video

from .test_cli_batch import _study


def _options_read(module) -> set[str]:
    """``options.<field>`` attributes in the module's source (all files of a package)."""
    path = Path(inspect.getfile(module))
    files = sorted(path.parent.glob("*.py")) if path.name == "__init__.py" else [path]
    found: set[str] = set()
    for f in files:
        for node in ast.walk(ast.parse(f.read_text())):
            if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                    and node.value.id == "options"):
                found.add(node.attr)
    return found - {"device"}


def test_each_metric_module_declares_what_it_reads_of_the_options():
    """The declaration and the code agree: a module that reads options.X declares X for its
    metrics, and declares nothing it does not read."""
    known = {f.name for f in fields(MetricOptions)}
    for module in _declaring_modules():
        declared = set().union(*(set(e.spec.reads) for e in module.ENTRIES))
        assert declared <= known, module.__name__
        assert _options_read(module) == declared, module.__name__


def test_readers_names_the_metrics_of_an_option():
    cgvqm = [e.spec.name for e in entries() if e.spec.name.startswith("cgvqm")]
    assert readers("precision") == cgvqm
    assert set(readers("viewing")) == {"flip", "cvvdp"}
    assert set(readers("learned_weights")) == {"lpips", "lpips-alex", "dists", "pieapp"}
    assert readers("viewing", ["psnr", "cgvqm-2"]) == []
    assert readers("viewing", ["psnr", "flip"]) == ["flip"]


def _pair(tmp_path: Path) -> list[str]:
    rng = np.random.default_rng(0)
    ref = rng.integers(0, 256, (4, 32, 32, 3), dtype=np.uint8)
    test = np.clip(ref.astype(int) + rng.integers(-9, 10, ref.shape), 0, 255).astype(np.uint8)
    return ["--ref", str(write_video(tmp_path / "r.mkv", ref, 8)),
            "--test", str(write_video(tmp_path / "t.mkv", test, 8))]


@pytest.mark.parametrize(("metric", "option", "for_whom"), [
    ("psnr", ["--precision", "fp16"], "cgvqm-2, cgvqm-5"),
    ("psnr", ["--pool", "mean"], "cgvqm-2, cgvqm-5"),
    ("ssim", ["--random-backbone", "0"], "cgvqm-2, cgvqm-5"),
    ("psnr", ["--display", "standard_fhd"], "flip, cvvdp"),
    ("cgvqm-2", ["--ppd", "40"], "flip, cvvdp"),
    ("cgvqm-2", ["--learned-weights", "lpips=x.pth"], "lpips"),
    ("flip", ["--seamless"], "cgvqm-2"),
])
def test_score_refuses_an_option_its_metric_does_not_read(capsys, tmp_path, metric, option,
                                                          for_whom):
    csv = tmp_path / "s.csv"
    rc = main(["score", *_pair(tmp_path), "--metric", metric, *option, "--csv", str(csv)])
    _, err = capsys.readouterr()
    assert rc == 2 and len(err.strip().splitlines()) == 1, err
    assert f"{option[0]} applies to" in err and for_whom in err and metric in err
    assert not csv.exists()


def test_score_accepts_defaults_given_explicitly(capsys, tmp_path):
    rc = main(["score", *_pair(tmp_path), "--metric", "psnr", "--pool", "max",
               "--precision", "auto", "--display", "standard_4k", "--patch-scale", "4"])
    out, err = capsys.readouterr()
    assert rc == 0 and out.startswith("psnr = "), err


def test_batch_refuses_an_option_no_asked_metric_reads(capsys, tmp_path):
    manifest = _study(tmp_path)
    out = tmp_path / "s.csv"
    rc = main(["batch", "--manifest", str(manifest), "--out", str(out), "--metrics",
               "psnr,ssim", "--ppd", "40"])
    _, err = capsys.readouterr()
    assert rc == 2 and "--ppd applies to flip, cvvdp, not to psnr, ssim" in err
    assert not out.exists()
    # one metric of several reading it is enough
    rc = main(["batch", "--manifest", str(manifest), "--out", str(out), "--metrics",
               "psnr,flip", "--ppd", "40"])
    capsys.readouterr()
    assert rc == 0 and out.exists()


def test_batch_names_a_reader_that_all_left_out_as_unavailable(capsys, tmp_path,
                                                                monkeypatch):
    """'all' takes the metrics that can run here; learned weights given in a folder that
    holds none leave the learned metrics out, which is said instead of 'not to psnr, ...'."""
    import os

    for var in [v for v in os.environ if v.startswith("CGVQM_") and "WEIGHTS" in v]:
        monkeypatch.delenv(var)
    (tmp_path / "no-weights").mkdir()
    manifest = _study(tmp_path)
    out = tmp_path / "s.csv"
    rc = main(["batch", "--manifest", str(manifest), "--out", str(out), "--metrics", "all",
               "--learned-weights", str(tmp_path / "no-weights")])
    _, err = capsys.readouterr()
    assert rc == 2 and err.count("\n") == 1, err
    assert "--learned-weights: lpips would read it but is not available here" in err
    assert "vgg16" in err and not out.exists()


@pytest.mark.parametrize(("metric", "option", "says"), [
    # a weights part the metric does not load: ignored before, even a missing file
    ("lpips", ["--learned-weights", "alexnet=missing.pth"],
     "lpips does not load alexnet weights (used by lpips-alex)"),
    ("lpips", ["--learned-sha256", "dists=" + "0" * 64],
     "lpips does not load dists weights (used by dists)"),
    # FLIP reads only the pixels per degree, which --ppd fixes
    ("flip", ["--ppd", "40", "--display", "sdr_fhd_24"], "which --ppd fixes"),
])
def test_score_refuses_parts_and_displays_its_metric_does_not_use(capsys, tmp_path, metric,
                                                                  option, says):
    rc = main(["score", *_pair(tmp_path), "--metric", metric, *option])
    _, err = capsys.readouterr()
    assert rc == 2 and err.count("\n") == 1 and says in err, err


def test_score_refuses_fps_for_two_video_files(capsys, tmp_path):
    pair = _pair(tmp_path)
    rc = main(["score", *pair, "--metric", "psnr", "--fps", "60"])
    _, err = capsys.readouterr()
    assert rc == 2 and "both inputs are video files" in err
    # a .npy input takes it
    np.save(tmp_path / "t.npy", np.zeros((4, 32, 32, 3), np.uint8))
    rc = main(["score", pair[0], pair[1], "--test", str(tmp_path / "t.npy"), "--metric",
               "psnr", "--fps", "8"])
    out, err = capsys.readouterr()
    assert rc == 0 and out.startswith("psnr = "), err


def test_batch_refuses_a_variant_its_weights_file_does_not_hold(capsys, tmp_path):
    """The weights file fixes CGVQM's variant: asking for the other (or both) would write the
    file's variant under every row, some twice."""
    from cgvqm_core.weights import resolve_weights, save_weights

    manifest = _study(tmp_path)
    weights = save_weights(tmp_path / "w5.json", resolve_weights("uniform", "cgvqm-5"))
    out = tmp_path / "s.csv"
    base = ["batch", "--manifest", str(manifest), "--out", str(out), "--random-backbone", "0",
            "--weights", str(weights)]
    for asked, names in ((["--variant", "cgvqm-2"], "cgvqm-2 was asked for"),
                         (["--metrics", "cgvqm-2,cgvqm-5"], "cgvqm-2 and cgvqm-5 were asked")):
        rc = main([*base, *asked])
        _, err = capsys.readouterr()
        assert rc == 2 and "holds cgvqm-5 weights" in err and names in err, err
        assert not out.exists()


def test_weights_fetch_refuses_a_backbone_file_it_would_skip(capsys):
    rc = main(["weights", "fetch", "--no-backbone", "--backbone-file", "r3d.pth"])
    _, err = capsys.readouterr()
    assert rc == 2 and "which --no-backbone skips" in err
