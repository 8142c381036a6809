"""A re-run of ``cgvq-study init`` with no options maps and copies the renders as the last
run did (kept in STUDY/init.json): a re-run used to fall back to the default patterns, and a
study transcoded once was silently re-copied from the lossy sources."""

from __future__ import annotations

import json

import numpy as np
from support.cli import study_init as init
from support.encode import encode

from stimuli_manifests import load_manifest, read_video, sha256_file, write_video
from study_app.init_choices import INIT_FILE

FPS = 30


def clip(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (8, 32, 48, 3), dtype=np.uint8)


def paths(study) -> dict[str, str]:
    m = load_manifest(study / "manifest.json").manifest
    return {e.id: e.path for e in [*m.references, *m.conditions]}


def test_a_rerun_keeps_the_transcode_and_no_transcode_undoes_it(tmp_path, capsys):
    renders, study = tmp_path / "renders", tmp_path / "study"
    encode(renders / "bistro" / "reference.mp4", clip(1), codec="libx264", pix_fmt="yuv420p",
           rate=FPS)
    write_video(renders / "bistro" / "blur_L1.mkv", clip(2), FPS)
    assert init(capsys, renders, "--out", study, "--transcode")[0] == 0
    transcoded = paths(study)
    assert transcoded["bistro"].endswith(".avi")
    code, out, _ = init(capsys, renders, "--out", study)
    assert code == 0 and "no changes" in out
    assert f"as the last init into {study}: --transcode utvideo" in out
    assert paths(study) == transcoded
    code, out, _ = init(capsys, renders, "--out", study, "--no-transcode")
    assert code == 0 and "as the last init" not in out
    exact = paths(study)
    assert exact["bistro"].endswith(".mp4")
    assert sha256_file(study / exact["bistro"]) == sha256_file(renders / "bistro" /
                                                               "reference.mp4")
    assert json.loads((study / INIT_FILE).read_text())["transcode"] is None
    assert init(capsys, renders, "--out", study, "--transcode", "--no-transcode")[0] == 2


def test_a_rerun_keeps_the_patterns_and_takes_a_new_scene(tmp_path, capsys):
    renders, study = tmp_path / "renders", tmp_path / "study"
    for seed, scene in enumerate(("sponza", "bistro")):
        write_video(renders / f"{scene}_GT.mkv", clip(seed), FPS)
        write_video(renders / f"{scene}_taa_q1.mkv", clip(seed + 10), FPS)
    patterns = ("--reference-pattern", "{scene}_GT.{ext}", "--pattern",
                "{scene}_{method}_q{level}.{ext}")
    assert init(capsys, renders, "--out", study, *patterns)[0] == 0
    write_video(renders / "gallery_GT.mkv", clip(7), FPS)
    write_video(renders / "gallery_taa_q1.mkv", clip(8), FPS)
    code, out, err = init(capsys, renders, "--out", study)
    assert code == 0, err
    assert "--pattern '{scene}_{method}_q{level}.{ext}' --reference-pattern " \
           "'{scene}_GT.{ext}'" in out
    assert {"gallery", "gallery_taa_L1"} <= set(paths(study))
    assert np.array_equal(read_video(study / paths(study)["gallery_taa_L1"]), clip(8))
    # one pattern given: the other is still the last run's
    code, out, err = init(capsys, renders, "--out", study, "--pattern",
                          "{scene}_{method}_q{level}.{ext}")
    assert code == 0 and "no changes" in out and "--reference-pattern '{scene}_GT" in out


def test_a_rerun_keeps_the_mapping_csv(tmp_path, capsys):
    renders, study = tmp_path / "renders", tmp_path / "study"
    write_video(renders / "take_a.mkv", clip(1), FPS)
    write_video(renders / "take_b.mkv", clip(2), FPS)
    table = tmp_path / "map.csv"
    table.write_text("path,scene,role,method,level,setting\ntake_a.mkv,hall,reference,,,\n"
                     "take_b.mkv,hall,test,blur,1,\n")
    assert init(capsys, renders, "--out", study, "--mapping", table)[0] == 0
    code, out, err = init(capsys, renders, "--out", study)
    assert code == 0 and "no changes" in out, err
    assert f"--mapping {table.resolve()}" in out
    assert json.loads((study / INIT_FILE).read_text())["mapping_csv"] == "../map.csv"
    # the three moved together still find each other
    moved = tmp_path / "moved"
    moved.mkdir()
    for item in (renders, study, table):
        item.rename(moved / item.name)
    code, out, err = init(capsys, moved / "renders", "--out", moved / "study")
    assert code == 0 and "no changes" in out, err
    assert f"--mapping {(moved / 'map.csv').resolve()}" in out


def test_an_unreadable_record_is_one_line(tmp_path, capsys):
    renders, study = tmp_path / "renders", tmp_path / "study"
    write_video(renders / "hall" / "reference.mkv", clip(1), FPS)
    write_video(renders / "hall" / "blur_L1.mkv", clip(2), FPS)
    assert init(capsys, renders, "--out", study)[0] == 0
    assert json.loads((study / INIT_FILE).read_text())["test_pattern"] is None  # defaults
    (study / INIT_FILE).write_text('{"format": "cgvq-init/1", "transcode": 5}')
    code, _, err = init(capsys, renders, "--out", study)
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "init.json cannot be read" in err and "Traceback" not in err


def test_a_rerun_on_another_folder_asks_before_it_removes_stimuli(tmp_path, capsys):
    """A mistyped renders folder removed every stimulus and deleted the copies (exit 0):
    now it is refused, naming the folder the study was made from, until --force; the same
    folder may still drop a stimulus whose render was deleted."""
    renders, other, study = tmp_path / "renders", tmp_path / "other", tmp_path / "study"
    for seed, scene in enumerate(("sponza", "bistro")):
        write_video(renders / scene / "reference.mkv", clip(seed), FPS)
        write_video(renders / scene / "blur_L1.mkv", clip(seed + 10), FPS)
    write_video(other / "kitchen" / "reference.mkv", clip(5), FPS)
    write_video(other / "kitchen" / "blur_L1.mkv", clip(6), FPS)
    assert init(capsys, renders, "--out", study)[0] == 0
    # kept relative to the study: a published study names no home folder
    assert json.loads((study / INIT_FILE).read_text())["renders"] == "../renders"
    before = paths(study)
    code, _, err = init(capsys, other, "--out", study)
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert f"was made from {renders.resolve()}" in err and "would remove 4 of its 4" in err
    assert paths(study) == before and all((study / p).is_file() for p in before.values())
    (renders / "bistro" / "blur_L1.mkv").unlink()
    code, out, _ = init(capsys, renders, "--out", study)
    assert code == 0 and "removed: bistro_blur_L1" in out
    code, out, _ = init(capsys, other, "--out", study, "--force")
    assert code == 0 and set(paths(study)) == {"kitchen", "kitchen_blur_L1"}


def test_a_rerun_that_maps_an_id_anew_says_so(tmp_path, capsys):
    """sponza_night's reference exported after a first run: its renders keep their ids but
    change reference and method; the re-run said only "added: sponza_night"."""
    renders, study = tmp_path / "renders", tmp_path / "study"
    write_video(renders / "sponza_ref.mkv", clip(1), FPS)
    write_video(renders / "sponza_dlss_q1.mkv", clip(2), FPS)
    write_video(renders / "sponza_night_xess_q1.mkv", clip(3), FPS)
    patterns = ("--reference-pattern", "{scene}_ref.{ext}", "--pattern",
                "{scene}_{method}_q{level}.{ext}")
    code, out, _ = init(capsys, renders, "--out", study, *patterns)
    assert code == 0 and "if 'sponza_night' is a scene of its own" in out
    write_video(renders / "sponza_night_ref.mkv", clip(4), FPS)
    code, out, _ = init(capsys, renders, "--out", study)
    assert code == 0 and "added: sponza_night\n" in out
    assert "sponza_night_xess_L1 (reference sponza -> sponza_night, method night_xess -> xess)" \
        in out
    m = load_manifest(study / "manifest.json").manifest
    cond = next(c for c in m.conditions if c.id == "sponza_night_xess_L1")
    assert (cond.reference, cond.method) == ("sponza_night", "xess")


def test_two_scenes_cannot_share_one_reference_and_a_stray_reference_copy_is_named(tmp_path,
                                                                                  capsys):
    """scene02's reference a copy of scene01's: every scene02 test would be compared with
    scene01's content (exit 0 before); a test that is another scene's reference is named."""
    renders = tmp_path / "renders"
    first = renders / "scene01" / "reference.mkv"
    write_video(first, clip(1), FPS)
    write_video(renders / "scene01" / "dlss_L1.mkv", clip(2), FPS)
    write_video(renders / "scene02" / "dlss_L1.mkv", clip(3), FPS)
    (renders / "scene02" / "reference.mkv").write_bytes(first.read_bytes())
    results = [init(capsys, renders, "--out", tmp_path / "study")]
    write_video(renders / "scene02" / "reference.mkv", clip(4), FPS)  # its own, now
    (renders / "scene02" / "fsr_L1.mkv").write_bytes(first.read_bytes())
    results.append(init(capsys, renders, "--out", tmp_path / "study"))
    (code, out, _), (code2, out2, _) = results
    assert code == 2
    row = next(line for line in out.splitlines() if "same reference" in line)
    assert "scene02/reference.mkv" in row and "the reference of scene 'scene01'" in row
    assert code2 == 0
    out = out2
    warned = next(line for line in out.splitlines() if "reference of scene 'scene01'" in line)
    assert warned.startswith("  warning: the same file as") and "(scene02/fsr_L1.mkv)" in warned


def test_a_test_with_another_colour_resolution_than_its_reference_is_named(tmp_path, capsys):
    """A 4:2:0 H.264 test beside an RGB (4:4:4) reference passed without a word."""
    renders = tmp_path / "renders"
    write_video(renders / "bistro" / "reference.mkv", clip(1), FPS)
    encode(renders / "bistro" / "x264_L1.mp4", clip(2), codec="libx264", pix_fmt="yuv420p",
           rate=FPS)
    write_video(renders / "bistro" / "blur_L2.mkv", clip(3), FPS)
    code, out, _ = init(capsys, renders, "--out", tmp_path / "study")
    assert code == 0
    chroma = [line for line in out.splitlines() if "colour resolution differs" in line]
    assert len(chroma) == 1 and "(bistro/x264_L1.mp4)" in chroma[0]
    assert "yuv420p (4:2:0), its reference bistro/reference.mkv is bgr0 (4:4:4)" in chroma[0]


def test_a_reference_whose_scene_differs_only_in_case_is_pointed_to(tmp_path):
    """Sponza_ref.mp4 beside sponza_TAA_q1.mp4: 'missing reference sponza' and 'Sponza has no
    test video' said nothing that linked them."""
    from stimuli_manifests.from_folder.mapping import map_by_pattern

    for name in ("Sponza_ref.mp4", "sponza_TAA_q1.mp4"):
        (tmp_path / name).write_bytes(b"")
    mapped = map_by_pattern(tmp_path, test_pattern="{scene}_{method}_q{level}.{ext}",
                            reference_pattern="{scene}_ref.{ext}")
    detail = next(p.detail for p in mapped.problems if p.kind == "missing reference")
    assert "Sponza_ref.mp4 is the reference of scene 'Sponza', which differs only in case" \
        in detail
