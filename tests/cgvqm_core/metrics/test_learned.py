"""LPIPS, LPIPS-AlexNet, DISTS and PieAPP: networks, weights files, and the metrics against
PIQ's own code (and the LPIPS authors' code as torchmetrics ships it).

No published weights are available offline, so the tests make weight files with random
numbers (fixed seeds) and check that:
- the networks have torchvision's published parameter counts and names, and load a
  torchvision-named state dict strictly; their convolution stacks equal a plain functional
  re-computation written out here;
- everything else (heads, normalisation, pooling, resizing, patching, averaging) equals
  PIQ 0.8's LPIPS/DISTS/PieAPP run on the same weights. PIQ gets its VGG-16 from
  ``torchvision.models.vgg16`` (a name bound in ``piq.perceptual``); the test replaces that
  name with a stand-in that returns this package's ``features`` network with the same random
  weights, and ``torch.hub.load_state_dict_from_url`` with a function that returns the test's
  head weights, so nothing is downloaded and only the backbone's conv stack is not PIQ's;
- the streamed scores through the registry, the CLI and ``batch`` use those files, refuse a
  wrong sha256 in one line, and never reach any download function.
"""

from __future__ import annotations

import hashlib
import json
import pickle
import socket
import sys
import types
import urllib.request
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from cgvqm_core.cli import main
from cgvqm_core.errors import CGVQMError
from cgvqm_core.metrics import MetricOptions, build_scorers, get_entry, score_reference
from cgvqm_core.metrics.learned import alexnet, files, pieapp, vgg
from stimuli_manifests import fill_checksums, load_manifest, save_manifest, write_video
from stimuli_manifests.tables import SCORES, read_table

from .conftest import as_batch, blurred, noisy, real_video
from .piq_loader import load_piq

FPS = 8
# torchvision's layouts, written out: (index in features, in, out, kernel, stride, padding)
VGG16_CONVS = [(0, 3, 64), (2, 64, 64), (5, 64, 128), (7, 128, 128), (10, 128, 256),
               (12, 256, 256), (14, 256, 256), (17, 256, 512), (19, 512, 512), (21, 512, 512),
               (24, 512, 512), (26, 512, 512), (28, 512, 512)]
VGG16_POOLS_AFTER = {2, 7, 14, 21, 28}  # a 2x2 max-pool follows these convolutions
ALEX_CONVS = [(0, 3, 64, 11, 4, 2), (3, 64, 192, 5, 1, 2), (6, 192, 384, 3, 1, 1),
              (8, 384, 256, 3, 1, 1), (10, 256, 256, 3, 1, 1)]
ALEX_POOLS_AFTER = {0, 3}  # 3x3 stride-2 max-pools (the last one, after conv 10, is unused)


@pytest.fixture(autouse=True)
def _no_user_weights(monkeypatch):
    """The developer's own weight locations must not leak into the tests."""
    monkeypatch.delenv(files.DIR_ENV, raising=False)
    for part in files.PARTS.values():
        monkeypatch.delenv(part.env, raising=False)
        monkeypatch.delenv(part.sha_env, raising=False)


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _random_features(convs: list[tuple], seed: int) -> dict[str, torch.Tensor]:
    """A torchvision-named ``features.*`` state dict with He-normal random weights."""
    g = torch.Generator().manual_seed(seed)
    sd = {}
    for c in convs:
        i, cin, cout = c[:3]
        k = c[3] if len(c) > 3 else 3
        sd[f"features.{i}.weight"] = torch.randn(cout, cin, k, k, generator=g) * (
            2.0 / (cout * k * k)) ** 0.5
        sd[f"features.{i}.bias"] = torch.randn(cout, generator=g) * 0.01
    return sd


def _l1_pieapp(seed: int) -> dict[str, torch.Tensor]:
    """PieAPP weights that make each patch's error 0.01 * the L1 distance of 256 of its
    features and every weight 1: a 'trained-like' metric that must order distortions."""
    torch.manual_seed(seed)
    sd = {k: v.clone() for k, v in pieapp.PieAPPNet().state_dict().items()}
    idx = torch.randperm(120832)[:256]
    w1 = torch.zeros(512, 120832)
    w1[torch.arange(256), idx] = 1.0
    w1[256 + torch.arange(256), idx] = -1.0  # relu(d) + relu(-d) = |d|
    sd.update({"fc1_score.weight": w1, "fc1_score.bias": torch.zeros(512),
               "fc2_score.weight": torch.ones(1, 512), "fc2_score.bias": torch.zeros(1),
               "fc1_weight.weight": torch.zeros(512, 2048), "fc1_weight.bias": torch.zeros(512),
               "fc2_weight.weight": torch.zeros(1, 512), "fc2_weight.bias": torch.ones(1),
               "ref_score_subtract.weight": torch.ones(1), "ref_score_subtract.bias":
               torch.zeros(1)})
    return sd


@pytest.fixture(scope="module")
def wfiles(tmp_path_factory):
    """Weight files with random numbers, in the published formats (names are not the
    published ones, so no published hash is expected of them)."""
    d = tmp_path_factory.mktemp("learned-weights")
    g = torch.Generator().manual_seed(7)
    heads = {f"lin{k}.model.1.weight": torch.rand(1, c, 1, 1, generator=g)
             for k, c in enumerate(vgg.TAP_CHANNELS)}
    aheads = {f"lin{k}.model.1.weight": torch.rand(1, c, 1, 1, generator=g)
              for k, c in enumerate(alexnet.TAP_CHANNELS)}
    a, b = torch.rand(1, 1475, 1, 1, generator=g), torch.rand(1, 1475, 1, 1, generator=g)
    total = a.sum() + b.sum()
    torch.manual_seed(3)
    pie = pieapp.PieAPPNet().state_dict()
    pie["fc2_weight.bias"] = torch.ones(1)  # patch weights near 1 (positive), as trained ones
    pie["ref_score_subtract.weight"] = pie["ref_score_subtract.weight"].reshape(1)  # as published
    content = {
        "vgg16": _random_features(VGG16_CONVS, 1),
        "alexnet": _random_features(ALEX_CONVS, 2),
        "lpips": heads, "lpips-alex": aheads,
        "dists": {"alpha": a / total, "beta": b / total},
        "pieapp": pie,
        "pieapp-l1": _l1_pieapp(4),
    }
    paths = {}
    for name, obj in content.items():
        paths[name] = d / f"random-{name}.pth"
        torch.save(obj, paths[name])
    return types.SimpleNamespace(
        dir=d, paths=paths, content=content, sha={k: _sha(p) for k, p in paths.items()},
        options=lambda **kw: MetricOptions(
            learned_weights={k: str(v) for k, v in paths.items() if k != "pieapp-l1"}, **kw))


def _frames(h: int, w: int, n: int = 2) -> tuple[torch.Tensor, torch.Tensor]:
    ref = real_video(n, h, w, image="chelsea" if h <= 250 else "astronaut")
    test = np.concatenate([noisy(ref[:1], 10), blurred(ref[1:2], 1.4),
                           ref[2:] // 2 + 60])[:n]
    return as_batch(test), as_batch(ref)


def _scorer(name: str, options: MetricOptions):
    (s,) = build_scorers([name], options)
    return s


# -- networks ----------------------------------------------------------------------------------


def _count(model: torch.nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())


def test_parameter_counts_and_names_are_torchvisions():
    with torch.device("meta"):
        assert _count(vgg.VGG16()) == 138_357_544
        assert _count(vgg.VGG16(classifier=False)) == 14_714_688
        assert _count(alexnet.AlexNet()) == 61_100_840
        assert _count(alexnet.AlexNet(classifier=False)) == 2_469_696
    want_vgg = {f"features.{c[0]}.{p}" for c in VGG16_CONVS for p in ("weight", "bias")}
    want_vgg |= {f"classifier.{i}.{p}" for i in (0, 3, 6) for p in ("weight", "bias")}
    assert set(vgg.expected_keys()) == want_vgg
    want_alex = {f"features.{c[0]}.{p}" for c in ALEX_CONVS for p in ("weight", "bias")}
    want_alex |= {f"classifier.{i}.{p}" for i in (1, 4, 6) for p in ("weight", "bias")}
    assert set(alexnet.expected_keys()) == want_alex
    assert vgg.expected_keys()["classifier.0.weight"] == (4096, 25088)
    assert alexnet.expected_keys()["classifier.1.weight"] == (4096, 9216)


def _load_part(part: str, path: Path) -> files.WeightsFile:
    return files.load(part, {part: str(path)})


@pytest.mark.slow  # about 7 s here: CI runs it after `make test` (.ci/run)
def test_torchvision_state_dicts_load_strictly(tmp_path, wfiles):
    sd = wfiles.content["vgg16"]
    full = vgg.expected_keys()
    # a complete torchvision dict (classifier entries as shape-only meta tensors)
    complete = dict(sd)
    complete.update({k: torch.empty(s, device="meta") for k, s in full.items()
                     if k.startswith("classifier.")})
    variants = {"complete": complete, "features": sd,
                "bare": {k[len("features."):]: v for k, v in sd.items()},
                "wrapped": {"state_dict": sd}}
    for name, obj in variants.items():
        p = tmp_path / f"{name}.pth"
        torch.save(obj, p)
        state = files.features_state(_load_part("vgg16", p), full)
        net = vgg.make_features()
        net.load_state_dict(state, strict=True)
        torch.testing.assert_close(net[28].weight, sd["features.28.weight"], rtol=0, atol=0)
    broken = {
        "missing": {k: v for k, v in sd.items() if k != "features.10.bias"},
        "unexpected": {**sd, "features.31.weight": torch.zeros(1)},
        "half classifier": {**sd, "classifier.6.bias": torch.zeros(1000)},
        "shape": {**sd, "features.0.weight": torch.zeros(64, 3, 5, 5)},
        "not a dict": [torch.zeros(3)],
    }
    for name, obj in broken.items():
        p = tmp_path / "broken.pth"
        torch.save(obj, p)
        with pytest.raises(CGVQMError) as e:
            files.features_state(_load_part("vgg16", p), full)
        assert str(p) in str(e.value), name
    # AlexNet too
    state = files.features_state(_load_part("alexnet", wfiles.paths["alexnet"]),
                                 alexnet.expected_keys())
    alexnet.make_features().load_state_dict(state, strict=True)


def _vgg_functional(sd: dict[str, torch.Tensor], x: torch.Tensor) -> list[torch.Tensor]:
    out = []
    for i, _, _ in VGG16_CONVS:
        x = F.relu(F.conv2d(x, sd[f"features.{i}.weight"], sd[f"features.{i}.bias"], padding=1))
        if i in VGG16_POOLS_AFTER:
            out.append(x)  # relu1_2, relu2_2, relu3_3, relu4_3, relu5_3
            x = F.max_pool2d(x, 2, 2)
    return out


def _alex_functional(sd: dict[str, torch.Tensor], x: torch.Tensor) -> list[torch.Tensor]:
    out = []
    for i, _, _, _, stride, pad in ALEX_CONVS:
        x = F.relu(F.conv2d(x, sd[f"features.{i}.weight"], sd[f"features.{i}.bias"],
                            stride=stride, padding=pad))
        out.append(x)
        if i in ALEX_POOLS_AFTER:
            x = F.max_pool2d(x, 3, 2)
    return out


def test_conv_stacks_equal_a_functional_recomputation(wfiles):
    x = as_batch(real_video(2, 67, 75, image="chelsea"))
    for part, arch, fn in (("vgg16", vgg, _vgg_functional), ("alexnet", alexnet,
                                                              _alex_functional)):
        sd = wfiles.content[part]
        net = arch.make_features()
        net.load_state_dict({k[len("features."):]: v for k, v in sd.items()}, strict=True)
        with torch.inference_mode():
            mine = list(vgg.tapped(net, x, arch.TAPS))
            want = fn(sd, x)
        assert [t.shape[1] for t in mine] == list(arch.TAP_CHANNELS)
        for a, b in zip(mine, want, strict=True):
            torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-6)


def test_minimum_sizes_are_the_networks_own():
    for name, arch in (("lpips", vgg), ("lpips-alex", alexnet)):
        n = get_entry(name).spec.min_size
        net = arch.make_features()
        with torch.inference_mode():
            list(vgg.tapped(net, torch.zeros(1, 3, n, n), arch.TAPS))
            with pytest.raises(RuntimeError):
                list(vgg.tapped(net, torch.zeros(1, 3, n - 1, n - 1), arch.TAPS))
    assert get_entry("pieapp").spec.min_size == pieapp.PATCH


# -- the metrics against PIQ ---------------------------------------------------------------


@pytest.fixture
def piq_standin(monkeypatch, wfiles):
    """PIQ with its VGG-16 replaced by this package's features (the same random weights) and
    its weight downloads by the test's head files."""
    piq = load_piq()
    perceptual = sys.modules["piq.perceptual"]

    def vgg16(pretrained: bool = False, progress: bool = True):
        net = vgg.make_features()
        sd = wfiles.content["vgg16"]
        net.load_state_dict({k[len("features."):]: v for k, v in sd.items()}, strict=True)
        return types.SimpleNamespace(features=net)

    monkeypatch.setattr(perceptual, "vgg16", vgg16)
    served: dict[str, object] = {}

    def from_url(url, *a, **k):
        name = url.rsplit("/", 1)[-1]
        return served[name]() if callable(served[name]) else served[name]

    monkeypatch.setattr(torch.hub, "load_state_dict_from_url", from_url)
    c = wfiles.content
    served["lpips_weights.pt"] = [c["lpips"][f"lin{k}.model.1.weight"] for k in range(5)]
    served["dists_weights.pt"] = c["dists"]
    served["PieAPPv0.1.pth"] = lambda: dict(torch.load(wfiles.paths["pieapp"]))
    return piq, served


def test_lpips_equals_piq(piq_standin, wfiles, monkeypatch):
    piq, _ = piq_standin
    t, r = _frames(72, 88)
    s = _scorer("lpips", wfiles.options())
    mine = s.score_frames(t, r)
    with torch.inference_mode():
        theirs = piq.LPIPS(reduction="none")(t, r).double().numpy()
    np.testing.assert_allclose(mine, theirs, rtol=1e-5)
    assert (mine > 0).all()
    # taps compared a few rows at a time (as for large frames) give the same numbers
    from cgvqm_core.metrics.learned import lpips

    monkeypatch.setattr(lpips, "STRIPE_PIXELS", 200)
    np.testing.assert_allclose(s.score_frames(t, r), theirs, rtol=1e-5)


@pytest.mark.parametrize("size", [(72, 88), (264, 280)], ids=["72x88", "264x280-resized"])
def test_dists_equals_piq(piq_standin, wfiles, size):
    piq, _ = piq_standin
    t, r = _frames(*size, n=1 if size[0] > 256 else 2)
    s = _scorer("dists", wfiles.options())
    mine = s.score_frames(t, r)
    with torch.inference_mode():
        theirs = piq.DISTS(reduction="none")(t, r).double().numpy()
    # DISTS = 1 - (a float32 sum near 1): absolute agreement to a few float32 ulps of 1
    np.testing.assert_allclose(mine, theirs, rtol=1e-5, atol=3e-7)
    assert ((mine > 0) & (mine < 1)).all()


@pytest.mark.parametrize("weights", ["pieapp", "pieapp-l1"])
def test_pieapp_equals_piq(piq_standin, wfiles, weights):
    piq, served = piq_standin
    served["PieAPPv0.1.pth"] = lambda: dict(torch.load(wfiles.paths[weights]))
    t, r = _frames(96, 151)  # 2 x 4 patches at stride 27, a 6-pixel strip left unused
    opts = wfiles.options()
    opts.learned_weights["pieapp"] = str(wfiles.paths[weights])
    s = _scorer("pieapp", opts)
    mine = s.score_frames(t, r)
    with torch.inference_mode():
        theirs = piq.PieAPP(reduction="none")(t, r).double().numpy()
    np.testing.assert_allclose(mine, theirs, rtol=1e-5)


def test_pieapp_bands_do_not_change_the_score(wfiles):
    net = pieapp.PieAPPNet()
    sd = dict(wfiles.content["pieapp"])
    sd["ref_score_subtract.weight"] = sd["ref_score_subtract.weight"].reshape(1, 1)
    net.load_state_dict(sd)
    t, r = _frames(120, 97)
    with torch.inference_mode():
        one = pieapp.pieapp(net, t, r, chunk=1)
        whole = pieapp.pieapp(net, t, r, chunk=10_000)
    np.testing.assert_allclose(one.numpy(), whole.numpy(), rtol=1e-6)
    assert pieapp.patch_grid(120, 97) == (3, 2)


def _torchmetrics_lpips(monkeypatch, wfiles, net: str):
    """torchmetrics' copy of the LPIPS authors' code (scaling layer, NetLinLayer) with a
    stand-in torchvision that returns this package's features with the random weights."""
    tm = pytest.importorskip("torchmetrics.functional.image.lpips")
    part, arch = ("vgg16", vgg) if net == "vgg" else ("alexnet", alexnet)

    def build(weights=None):
        f = arch.make_features()
        sd = wfiles.content[part]
        f.load_state_dict({k[len("features."):]: v for k, v in sd.items()}, strict=True)
        return types.SimpleNamespace(features=f)

    fake = types.ModuleType("torchvision")
    fake.models = types.SimpleNamespace(vgg16=build, alexnet=build)
    monkeypatch.setitem(sys.modules, "torchvision", fake)
    monkeypatch.setattr(tm, "_TORCHVISION_AVAILABLE", True)
    heads = wfiles.paths["lpips" if net == "vgg" else "lpips-alex"]
    return tm._LPIPS(pretrained=True, net=net, pnet_rand=True, model_path=str(heads)).eval()


@pytest.mark.parametrize(("name", "net"), [("lpips", "vgg"), ("lpips-alex", "alex")])
def test_lpips_equals_the_authors_formulation(monkeypatch, wfiles, name, net):
    model = _torchmetrics_lpips(monkeypatch, wfiles, net)
    t, r = _frames(72, 88)
    mine = _scorer(name, wfiles.options()).score_frames(t, r)
    with torch.inference_mode():
        theirs = model(t, r, normalize=True).reshape(-1).double().numpy()
    # its features are normalised with sqrt(|f|^2 + 1e-8), the authors' and PIQ's with
    # |f| + 1e-10: a difference of order 1e-8 / |f|^2
    np.testing.assert_allclose(mine, theirs, rtol=1e-5)


@pytest.mark.slow  # about 7 s here: CI runs it after `make test` (.ci/run)
def test_identity_and_symmetry(wfiles):
    t, r = _frames(80, 96)
    opts = wfiles.options()
    for name in ("lpips", "lpips-alex", "dists"):
        s = _scorer(name, opts)
        assert np.abs(s.score_frames(r, r)).max() < 1e-6, name  # alpha + beta sum to 1
        np.testing.assert_allclose(s.score_frames(t, r), s.score_frames(r, t), rtol=1e-6)
    # PieAPP of an image with itself: every patch has zero feature difference, so its
    # error is ref_score_subtract(0.01 * fc2_score(relu(fc1_score.bias))), whatever weight
    sd = wfiles.content["pieapp"]
    e = sd["fc2_score.weight"] @ F.relu(sd["fc1_score.bias"]) + sd["fc2_score.bias"]
    want = float(sd["ref_score_subtract.weight"] * 0.01 * e + sd["ref_score_subtract.bias"])
    got = _scorer("pieapp", opts).score_frames(r, r)
    np.testing.assert_allclose(got, want, rtol=1e-5)


LEVELS = {"blur": [0.6, 1.2, 2.0, 3.0], "noise": [4.0, 8.0, 16.0, 32.0]}


@pytest.mark.slow  # about 13 s: CI runs it with test_monotonic.py after `make test` (.ci/run)
def test_graded_blur_and_noise_are_ordered(tmp_path, wfiles):
    """Through the streamed path on a real photograph. LPIPS and DISTS order these with
    random weights (so does PIQ with the same weights: the cross-checks above); PieAPP with
    random weights does not (its patch errors barely move), so it is checked with weights
    that make it an L1 distance of its features (``_l1_pieapp``)."""
    ref = real_video(2, 96, 96, image="chelsea")
    r = write_video(tmp_path / "ref.mkv", ref, FPS)
    tests = []
    for kind, levels in LEVELS.items():
        for i, lv in enumerate(levels):
            v = blurred(ref, lv) if kind == "blur" else noisy(ref, lv, seed=i)
            tests.append(write_video(tmp_path / f"{kind}{i}.mkv", v, FPS))
    opts = wfiles.options()
    opts.learned_weights["pieapp"] = str(wfiles.paths["pieapp-l1"])
    names = ["lpips", "lpips-alex", "dists", "pieapp"]
    results = score_reference(r, tests, build_scorers(names, opts))
    for j, name in enumerate(names):
        for k, kind in enumerate(LEVELS):
            scores = [results[4 * k + i][j].score for i in range(4)]
            assert (np.diff(scores) > 0).all(), f"{name} does not order {kind}: {scores}"


# -- files, hashes and no downloads -----------------------------------------------------------


def test_unavailable_without_files_and_nothing_downloads(monkeypatch, wfiles):
    calls = []

    def refuse(*a, **k):
        calls.append(a)
        raise AssertionError("network access")

    for mod, attr in ((urllib.request, "urlopen"), (torch.hub, "load_state_dict_from_url"),
                      (torch.hub, "download_url_to_file"), (torch.hub, "load"),
                      (socket, "create_connection"), (socket.socket, "connect")):
        monkeypatch.setattr(mod, attr, refuse)
    # no bundled copies either: only the files given count
    monkeypatch.setattr(files, "_bundled", lambda part: None)
    for name, needs in (("lpips", "vgg16-397923af.pth"), ("lpips-alex", "alex.pth"),
                        ("dists", "weights.pt"), ("pieapp", "PieAPPv0.1.pth")):
        a = get_entry(name).availability()
        assert not a.ok and "nothing is downloaded" in a.reason and needs in a.reason
        assert "\n" not in a.reason
        with pytest.raises(CGVQMError, match="not available here"):
            build_scorers([name], MetricOptions())
    # with the files, everything builds and scores, still without any download
    t, r = _frames(64, 64)
    for s in build_scorers(["lpips", "lpips-alex", "dists", "pieapp"], wfiles.options()):
        assert np.isfinite(s.score_frames(t, r)).all()
    assert calls == []


def test_files_are_found_in_folders_env_and_hub_cache(monkeypatch, tmp_path, wfiles):
    monkeypatch.setattr(files, "_bundled", lambda part: None)
    folder = tmp_path / "w"
    folder.mkdir()
    (folder / "alex.pth").write_bytes(wfiles.paths["lpips-alex"].read_bytes())
    monkeypatch.setenv("CGVQM_LEARNED_WEIGHTS_DIR", str(folder))
    monkeypatch.setenv("CGVQM_ALEXNET_WEIGHTS", str(wfiles.paths["alexnet"]))
    assert get_entry("lpips-alex").availability().ok
    (s,) = build_scorers(["lpips-alex"], MetricOptions())
    assert s.weights[1].origin.startswith("$CGVQM_LEARNED_WEIGHTS_DIR")
    assert s.weights[0].origin == "$CGVQM_ALEXNET_WEIGHTS"
    # PIQ's cached file names in the torch hub cache (TORCH_HOME is the test's)
    hub = files.hub_checkpoints()
    hub.mkdir(parents=True)
    (hub / "PieAPPv0.1.pth").write_bytes(wfiles.paths["pieapp"].read_bytes())
    assert get_entry("pieapp").availability().ok
    (p,) = build_scorers(["pieapp"], MetricOptions())
    assert p.weights[0].origin == "torch hub cache"
    assert p.provenance()["weights"]["pieapp"]["published"].startswith("no")
    # an explicitly named file that does not exist never falls through to another one
    monkeypatch.setenv("CGVQM_PIEAPP_WEIGHTS", str(tmp_path / "nope.pth"))
    a = get_entry("pieapp").availability()
    assert not a.ok and "nope.pth: no such file" in a.reason


def test_bundled_published_heads_are_used_and_recognised():
    """torchmetrics ships the LPIPS v0.1 heads and the DISTS weights: their sha256 are the
    published ones, so they are found without any option."""
    pytest.importorskip("torchmetrics")
    for part in ("lpips", "lpips-alex", "dists"):
        found = files.locate(part)
        assert found is not None and found[1] == "installed package copy", part
        wf = files.load(part)
        assert wf.published and wf.sha256 == files.PARTS[part].published[0][0]
    a, b = files.dists_alpha_beta(files.load("dists"), 1475)
    assert float(a.sum() + b.sum()) == pytest.approx(1.0, abs=1e-6)  # so DISTS(x, x) = 0
    heads = files.lpips_heads(files.load("lpips"), vgg.TAP_CHANNELS)
    assert [h.numel() for h in heads] == list(vgg.TAP_CHANNELS)
    assert all((h >= 0).all() for h in heads)


def test_hashes_are_checked(tmp_path, wfiles):
    vgg_file = wfiles.paths["vgg16"]
    ok = files.load("vgg16", {"vgg16": str(vgg_file)}, stated_sha256={"vgg16":
                                                                      wfiles.sha["vgg16"]})
    assert ok.sha256 == wfiles.sha["vgg16"] and ok.published is None
    with pytest.raises(CGVQMError, match="is not the expected"):
        files.load("vgg16", {"vgg16": str(vgg_file)}, stated_sha256={"vgg16": "0" * 64})
    with pytest.raises(CGVQMError, match="64 hex digits"):
        files.load("vgg16", {"vgg16": str(vgg_file)}, stated_sha256={"vgg16": "abc"})
    # a file under torchvision's published name must be the published file
    fake = tmp_path / "vgg16-397923af.pth"
    fake.write_bytes(vgg_file.read_bytes())
    with pytest.raises(CGVQMError, match=r"not that of the published vgg16-397923af\.pth"):
        files.load("vgg16", {"vgg16": str(fake)})
    # code in a pickle is refused by the safe loader
    evil = tmp_path / "evil.pth"
    evil.write_bytes(pickle.dumps(types.SimpleNamespace(a=1), protocol=2))
    with pytest.raises(CGVQMError, match="safe loader"):
        files.load("dists", {"dists": str(evil)})


# -- command line and batch ------------------------------------------------------------------


def _run(capsys, *args) -> tuple[int, str, str]:
    rc = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return rc, out, err


def _weights_args(wfiles, *parts: str) -> list[str]:
    out = []
    for p in parts:
        out += ["--learned-weights", f"{p}={wfiles.paths[p]}"]
    return out


def test_cli_score_with_local_weights(capsys, tmp_path, wfiles):
    ref = real_video(3, 72, 80, image="chelsea")
    test = noisy(ref, 12)
    r = write_video(tmp_path / "r.mkv", ref, FPS)
    t = write_video(tmp_path / "t.mkv", test, FPS)
    args = ["score", "--ref", r, "--test", t, *_weights_args(wfiles, "vgg16", "lpips")]
    rc, out, err = _run(capsys, *args, "--metric", "lpips", "--json")
    assert rc == 0, err
    doc = json.loads(out)
    direct = _scorer("lpips", wfiles.options()).score_frames(as_batch(test), as_batch(ref))
    np.testing.assert_allclose(doc["per_frame"], direct, rtol=1e-6)
    assert doc["score"] == pytest.approx(float(np.mean(direct)), rel=1e-6)
    assert doc["direction"] == "lower-better"
    prov = doc["provenance"]
    assert prov["weights_sha256"] == wfiles.sha["lpips"]
    assert prov["backbone_sha256"] == wfiles.sha["vgg16"]
    # a stated hash that does not match: one line, exit 2
    rc, _, err = _run(capsys, *args, "--metric", "lpips", "--learned-sha256",
                      f"lpips={'1' * 64}")
    assert rc == 2 and "is not the expected" in err.splitlines()[-1]
    assert "Traceback" not in err
    rc, _, err = _run(capsys, *args, "--metric", "lpips", "--learned-sha256",
                      f"lpips={wfiles.sha['lpips']}")
    assert rc == 0, err
    rc, _, err = _run(capsys, "score", "--ref", r, "--test", t, "--metric", "lpips",
                      "--learned-weights", "nonsense")
    assert rc == 2 and "PART=PATH" in err and err.count("\n") == 1  # before any loading
    # a file that is not weights: one error line, no hash warning before it, and not torch's
    # advice to load it with weights_only=False
    garbage = tmp_path / "garbage.pth"
    garbage.write_text("not weights {")
    rc, _, err = _run(capsys, "score", "--ref", r, "--test", t, "--metric", "lpips",
                      "--learned-weights", f"vgg16={wfiles.paths['vgg16']}",
                      "--learned-sha256", f"vgg16={wfiles.sha['vgg16']}",
                      "--learned-weights", f"lpips={garbage}")
    assert rc == 2 and err.count("\n") == 1, err
    assert "not a PyTorch file of tensors only" in err and "weights_only" not in err
    # a folder with the files under their published names
    folder = tmp_path / "folder"
    folder.mkdir()
    (folder / "PieAPPv0.1.pth").write_bytes(wfiles.paths["pieapp"].read_bytes())
    rc, out, err = _run(capsys, "score", "--ref", r, "--test", t, "--metric", "pieapp",
                        "--learned-weights", folder)
    assert rc == 0 and out.startswith("pieapp = "), err


# about 10 s: CI runs it after `make test` (.ci/run), as `make test-slow` does
@pytest.mark.slow
def test_batch_rows_carry_weights_hashes_and_resume(capsys, tmp_path, wfiles, monkeypatch):
    root = tmp_path / "videos"
    ref = real_video(3, 72, 72, image="chelsea")
    write_video(root / "src.mkv", ref, FPS)
    conds = []
    for lv in (1, 2):
        write_video(root / f"d{lv}.mkv", blurred(ref, 1.0 * lv), FPS)
        conds.append({"reference": "SRC01", "path": f"d{lv}.mkv", "method": "blur",
                      "level": lv})
    doc = {"format": "cgvq-manifest/1", "study_id": "t", "root": "videos",
           "references": [{"path": "src.mkv"}], "conditions": conds}
    manifest = tmp_path / "manifest.json"
    manifest.write_text(json.dumps(doc))
    save_manifest(fill_checksums(load_manifest(manifest)), manifest)
    out = tmp_path / "scores.csv"
    monkeypatch.setenv("CGVQM_PIEAPP_WEIGHTS", str(wfiles.paths["pieapp"]))
    base = ["batch", "--manifest", manifest, "--out", out, "--metrics",
            "lpips,dists,pieapp", *_weights_args(wfiles, "vgg16", "lpips", "dists")]
    rc, stdout, err = _run(capsys, *base)
    assert rc == 0, err
    rows = read_table(out, SCORES)
    assert len(rows) == 6
    by = {(r["stimulus"], r["metric"]): r for r in rows}
    for stim in ("SRC01_HRC01", "SRC01_HRC02"):
        lp, di, pa = (by[(stim, m)] for m in ("lpips", "dists", "pieapp"))
        assert lp["weights_sha256"] == wfiles.sha["lpips"]
        assert lp["backbone"] == wfiles.paths["vgg16"].name
        assert lp["backbone_sha256"] == di["backbone_sha256"] == wfiles.sha["vgg16"]
        assert di["weights_sha256"] == wfiles.sha["dists"]
        assert pa["weights_sha256"] == wfiles.sha["pieapp"] and pa["backbone"] == ""
        assert lp["direction"] == "lower-better"
        assert json.loads(lp["versions"])["weights"]["lpips"]["published"].startswith("no")
    assert float(by[("SRC01_HRC01", "lpips")]["score"]) < float(
        by[("SRC01_HRC02", "lpips")]["score"])
    rc, stdout, _ = _run(capsys, *base)
    assert "0 scored, 2 already" in stdout
    # other weights (another file) are other numbers: a second dists row per stimulus in
    # this file is refused (the analysis would keep one of the two); a new file takes them
    other = tmp_path / "dists2.pt"
    c = wfiles.content["dists"]
    torch.save({"alpha": c["beta"], "beta": c["alpha"]}, other)
    again = ["--metrics", "dists", *_weights_args(wfiles, "vgg16"), "--learned-weights",
             f"dists={other}"]
    rc, _, err = _run(capsys, *base[:5], *again)
    assert rc == 2 and "use a new --out" in err
    assert len(read_table(out, SCORES)) == 6
    rc, stdout, _ = _run(capsys, *base[:4], tmp_path / "scores2.csv", *again)
    assert rc == 0 and "2 scored" in stdout
    assert len(read_table(tmp_path / "scores2.csv", SCORES)) == 2


def test_learned_metrics_refuse_another_range_grey_and_half(wfiles):
    """0..255 input gave LPIPS and DISTS a plausible number (the ImageNet normalisation
    assumes [0, 1]); the networks themselves refuse it, as the image metrics do."""
    t, r = _frames(80, 96)
    opts = wfiles.options()
    for name in ("lpips", "lpips-alex", "dists", "pieapp"):
        s = _scorer(name, opts)
        fine = s.score_frames(t, r)
        assert np.isfinite(fine).all(), name
        for bad, words in [((t * 255, r * 255), r"spans 0\.?\d*\.\.2\d\d"),
                           ((t, r.half()), "float32 or float64"),
                           ((t[:, :1], r[:, :1]), "C 3"),
                           ((t.permute(0, 2, 3, 1), r.permute(0, 2, 3, 1)), "channels last")]:
            with pytest.raises(ValueError, match=words):
                s.score_frames(*bad)
