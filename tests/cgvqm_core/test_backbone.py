"""The VideoResNet family: torchvision's names and sizes, truncation, BN folding."""

from __future__ import annotations

import pytest
import torch

from cgvqm_core.backbone import build_backbone, expected_keys
from cgvqm_core.errors import CGVQMError
from cgvqm_core.features import FeatureNet
from cgvqm_core.hub import (
    BACKBONE_FILE,
    load_backbone_file,
    random_backbone,
    resolve_backbone,
)

# parameter counts published in torchvision's model documentation
PUBLISHED_PARAMS = {"r3d_18": 33_371_472, "mc3_18": 11_695_440, "r2plus1d_18": 31_505_325}


@pytest.mark.parametrize("arch", list(PUBLISHED_PARAMS))
def test_parameter_counts_match_torchvision(arch):
    with torch.device("meta"):
        model = build_backbone(arch)
    assert sum(p.numel() for p in model.parameters()) == PUBLISHED_PARAMS[arch]


def test_torchvision_key_names():
    keys = expected_keys("r3d_18")
    for k in ("stem.0.weight", "stem.1.running_mean", "layer1.0.conv1.0.weight",
              "layer1.0.conv1.1.weight", "layer2.0.downsample.0.weight",
              "layer4.1.conv2.1.running_var", "fc.weight", "fc.bias"):
        assert k in keys
    assert keys["stem.0.weight"] == (64, 3, 3, 7, 7)
    assert keys["layer2.0.downsample.0.weight"] == (128, 64, 1, 1, 1)
    assert "layer1.0.downsample.0.weight" not in keys
    r21 = expected_keys("r2plus1d_18")
    assert r21["stem.0.weight"] == (45, 3, 1, 7, 7)
    assert r21["layer1.0.conv1.0.0.weight"] == (144, 64, 1, 3, 3)  # midplanes 144
    assert expected_keys("mc3_18")["layer2.0.conv1.0.weight"] == (128, 64, 1, 3, 3)


def test_strict_load_and_shapes(state_dict, backbone_file):
    model = build_backbone("r3d_18")
    model.load_state_dict(torch.load(backbone_file, weights_only=True), strict=True)
    model.eval()
    with torch.inference_mode():
        out = model(torch.randn(1, 3, 4, 32, 32))
        levels = [a.shape for a in model.levels(torch.randn(1, 3, 4, 32, 32), 6)]
    assert out.shape == (1, 400)
    assert [s[1] for s in levels] == [3, 64, 64, 128, 256, 512]
    assert levels[1][2:] == (4, 16, 16) and levels[3][2:] == (2, 8, 8)


def test_cgvqm2_net_has_no_upper_layers(backbone):
    net = FeatureNet(backbone, 3)
    names = {n.split(".")[0] for n, _ in net.model.named_parameters()}
    assert names == {"stem", "layer1"}


def test_folded_channels_last_net_equals_plain_network(state_dict, backbone):
    plain = build_backbone("r3d_18")
    plain.load_state_dict(state_dict)
    plain.eval()
    fast = FeatureNet(backbone, 6)
    x = torch.randn(2, 3, 5, 20, 24)
    with torch.inference_mode():
        want = list(plain.levels(x, 6))
        got = list(fast.levels(x.contiguous(memory_format=torch.channels_last_3d)))
    for lv, (w, g) in enumerate(zip(want, got, strict=True)):
        if lv > 0:
            w = w / (w.pow(2).sum(1, keepdim=True).sqrt() + 1e-10)
        torch.testing.assert_close(g, w, rtol=1e-4, atol=1e-5)


def test_random_backbone_is_seeded_and_labelled():
    a, b = random_backbone(3), random_backbone(3)
    assert a.sha256 == b.sha256 and a.label == "random-seed-3" and a.is_random
    assert random_backbone(4).sha256 != a.sha256


def test_backbone_file_env_and_errors(backbone_file, tmp_path, monkeypatch, caplog):
    with caplog.at_level("WARNING", logger="cgvqm_core.hub"):
        bb = load_backbone_file(backbone_file)
    # a file of random weights is not the published one, whatever its name: said so
    assert any("not torchvision's Kinetics-400 R3D-18 file" in r.getMessage()
               for r in caplog.records)
    assert len(bb.sha256) == 64 and not bb.is_random
    monkeypatch.setenv("CGVQM_BACKBONE", str(backbone_file))
    assert resolve_backbone().sha256 == bb.sha256
    monkeypatch.delenv("CGVQM_BACKBONE")
    with pytest.raises(CGVQMError, match="--backbone PATH"):
        resolve_backbone()  # offline, nothing cached
    bad = tmp_path / "partial.pth"
    torch.save({"stem.0.weight": torch.zeros(64, 3, 3, 7, 7)}, bad)
    with pytest.raises(CGVQMError, match="missing"):
        load_backbone_file(bad)
    wrong_name = tmp_path / BACKBONE_FILE
    wrong_name.write_bytes(backbone_file.read_bytes())
    with pytest.raises(CGVQMError, match="b3b3357e"):
        load_backbone_file(wrong_name)
