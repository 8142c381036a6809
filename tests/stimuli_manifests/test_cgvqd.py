"""The CG-VQD study design template matches the paper's design."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

from stimuli_manifests import load_manifest, validate_manifest
from stimuli_manifests.cli import main as cli_main

CGVQD = Path(__file__).resolve().parents[2] / "stimuli_manifests" / "cgvqd.json"


def test_cgvqd_design():
    loaded = load_manifest(CGVQD)
    m = loaded.manifest
    assert validate_manifest(loaded, structure_only=True).ok
    assert len(m.references) == 15
    assert m.protocol.repetitions == 3 and m.protocol.hidden_reference
    for ref in m.references:
        assert (ref.width, ref.height) == (1024, 1024)
        expected_fps = 60 if ref.scene in ("Meerkat", "Infiltrator") else 30
        assert ref.fps == expected_fps and ref.frames == 3 * expected_fps
    design: dict[str, dict[str, list[str]]] = defaultdict(lambda: defaultdict(list))
    for c in sorted(m.conditions, key=lambda c: c.level):
        design[c.method][m.scene_of(c.reference)].append(c.setting)
    spp = ["4 spp", "16 spp", "64 spp", "256 spp"]
    assert design["path_tracing"] == {"Jungle1": spp, "Jungle2": spp}
    assert dict(design["neural_denoising"]) == {
        s: ["2 spp", "4 spp", "8 spp"] for s in ("ZeroDay", "Bistro")
    }
    assert set(design["xess_upscaling"]) == {"Coils", "Mushroom", "Street", "Park"}
    assert design["xess_upscaling"]["Coils"][0] == "1/3 resolution"
    assert set(design["boosted_ghosting_flicker"]) == {"Bridge", "Park", "Street"}
    assert all(len(v) == 3 for v in design["boosted_ghosting_flicker"].values())
    assert design["gaussian_splatting"]["Dock"] == [
        "125K splats",
        "250K splats",
        "500K splats",
        "1000K splats",
    ]
    assert design["gaussian_splatting"]["Clothes"] == [
        "87K splats",
        "175K splats",
        "375K splats",
        "750K splats",
    ]
    assert design["frame_interpolation"]["Meerkat"][0] == "12 to 60 fps"
    assert set(design["frame_interpolation"]) == {"Meerkat", "Infiltrator"}
    assert design["variable_rate_shading"]["House"][-1] == "50% shading budget"
    assert set(design["variable_rate_shading"]) == {"House", "Market"}
    assert len(m.conditions) == 63 and len(m.stimuli()) == 78


def test_cli_structure_only_and_missing_dataset(capsys, tmp_path):
    assert cli_main(["validate", str(CGVQD), "--structure-only"]) == 0
    assert "OK: structure valid" in capsys.readouterr().out
    assert cli_main(["validate", str(CGVQD), "--root", str(tmp_path)]) == 1
    assert "does not exist" in capsys.readouterr().out
    assert cli_main(["validate", str(tmp_path / "nope.json")]) == 2
    assert "manifest not found" in capsys.readouterr().err
