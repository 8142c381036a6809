"""A renders folder named the lab's way: init reads patterns off the names and suggests
them only when they map every file, each to the scene, method and level it was written as."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from support.cli import study_init as init

from stimuli_manifests import load_manifest, write_video
from stimuli_manifests.from_folder.mapping import map_by_pattern, scan_folder
from stimuli_manifests.from_folder.suggest import suggest_patterns


def touch(folder: Path, names: list[str]) -> None:
    for name in names:
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        (folder / name).write_bytes(b"")


def truth(mapping) -> set[tuple[str, str, str, str | None, int | None]]:
    return {(v.path.as_posix(), v.scene, v.role, v.method, v.level) for v in mapping.videos}


CASES = {
    "flat, underscores": (
        {"sponza_ref.mp4": ("sponza", None, None), "sponza_TAA_q1.mp4": ("sponza", "TAA", 1),
         "sponza_FSR_q2.mp4": ("sponza", "FSR", 2), "bistro_ref.mp4": ("bistro", None, None),
         "bistro_TAA_q1.mp4": ("bistro", "TAA", 1)},
        "{scene}_ref.{ext}", "{scene}_{method}_q{level}.{ext}"),
    "scene folders, GT": (
        {"scene01/GT.mov": ("scene01", None, None),
         "scene01/dlss_perf-1.mov": ("scene01", "dlss_perf", 1),
         "scene01/dlss_perf-2.mov": ("scene01", "dlss_perf", 2),
         "scene02/GT.mov": ("scene02", None, None), "scene02/fsr-1.mov": ("scene02", "fsr", 1)},
        "{scene}/GT.{ext}", "{scene}/{method}-{level}.{ext}"),
    "a scene name holding the separator": (
        {"sponza_atrium-ground_truth.mkv": ("sponza_atrium", None, None),
         "sponza_atrium-DLSS_crf23.mkv": ("sponza_atrium", "DLSS", 23),
         "bistro-ground_truth.mkv": ("bistro", None, None),
         "bistro-DLSS_crf30.mkv": ("bistro", "DLSS", 30)},
        "{scene}-ground_truth.{ext}", "{scene}-{method}_crf{level}.{ext}"),
    "sample counts with a unit (a renderer's naming)": (
        {"sponza/reference.mp4": ("sponza", None, None),
         "sponza/ours_4spp.mp4": ("sponza", "ours", 4),
         "sponza/ours_64spp.mp4": ("sponza", "ours", 64),
         "sponza/path_tracing_16spp.mp4": ("sponza", "path_tracing", 16),
         "bistro/reference.mp4": ("bistro", None, None),
         "bistro/ours_4spp.mp4": ("bistro", "ours", 4)},
        "{scene}/reference.{ext}", "{scene}/{method}_{level}spp.{ext}"),
}


@pytest.mark.parametrize("case", CASES)
def test_a_suggestion_maps_every_file_as_it_was_written(tmp_path, case):
    files, reference_pattern, test_pattern = CASES[case]
    touch(tmp_path, list(files))
    hint = suggest_patterns(tmp_path, scan_folder(tmp_path).videos)
    assert hint is not None
    assert (hint.reference_pattern, hint.test_pattern) == (reference_pattern, test_pattern)
    mapped = map_by_pattern(tmp_path, test_pattern=hint.test_pattern,
                            reference_pattern=hint.reference_pattern)
    assert truth(mapped) == {(p, s, "test" if m else "reference", m, lv)
                             for p, (s, m, lv) in files.items()}
    assert hint.videos == len(files) and hint.scenes == len({s for s, _, _ in files.values()})


@pytest.mark.parametrize("names", [
    ["a/reference.mp4", "a/dlss_perf.mp4", "a/dlss_quality.mp4"],  # no level in the names
    # two of four files fit no rule: more than a stray
    ["sponza_ref.mp4", "sponza_TAA_q1.mp4", "sponza_notes_final.mp4", "notes_v2_final.mp4"],
    ["sponza_TAA_q1.mp4", "sponza_TAA_q2.mp4"],  # no reference
])
def test_no_suggestion_unless_every_file_but_a_stray_maps(tmp_path, names):
    touch(tmp_path, names)
    assert suggest_patterns(tmp_path, scan_folder(tmp_path).videos) is None


def test_init_suggests_the_flags_and_they_build_the_study(tmp_path, capsys):
    renders = tmp_path / "renders"
    rng = np.random.default_rng(0)
    for scene in ("sponza", "bistro"):
        write_video(renders / f"{scene}-REF.mkv", rng.integers(0, 256, (6, 32, 32, 3),
                                                               dtype=np.uint8), 30)
        for level in (1, 2):
            write_video(renders / f"{scene}-taa_L{level}.mkv",
                        rng.integers(0, 256, (6, 32, 32, 3), dtype=np.uint8), 30)
    code, _, err = init(capsys, renders, "--out", tmp_path / "study")
    assert code == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert "(6 video file(s) found, e.g. " in err and "map all 6 (2 scene(s))" in err
    flags = "--reference-pattern '{scene}-REF.{ext}' --pattern '{scene}-{method}_L{level}.{ext}'"
    assert flags in err
    code, _, err = init(capsys, renders, "--out", tmp_path / "study",
                        "--reference-pattern", "{scene}-REF.{ext}",
                        "--pattern", "{scene}-{method}_L{level}.{ext}")
    assert code == 0, err
    ids = {s.id for s in load_manifest(tmp_path / "study" / "manifest.json").manifest.stimuli()}
    assert {"sponza", "bistro", "sponza_taa_L1", "bistro_taa_L2"} <= ids


def test_without_a_suggestion_init_says_where_to_go(tmp_path, capsys):
    renders = tmp_path / "renders"
    touch(renders, ["take1.mp4", "take2.mp4"])
    code, _, err = init(capsys, renders, "--out", tmp_path / "study")
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "(2 video file(s) found, e.g. take1.mp4); give --reference-pattern and --pattern" \
        in err and "--mapping CSV" in err


def test_a_flat_scene_without_its_reference_is_named_when_it_is_the_only_other(tmp_path):
    """With only sponza's reference, sponza_atrium_dlss_L1 was method 'atrium_dlss' of
    sponza without a word (the warning needed 'dlss' to be a method of a third scene)."""
    touch(tmp_path, ["sponza_reference.mp4", "sponza_dlss_L1.mp4", "sponza_fsr_L1.mp4",
                     "sponza_atrium_dlss_L1.mp4", "sponza_atrium_fsr_L1.mp4"])
    mapped = map_by_pattern(tmp_path, test_pattern="{scene}_{method}_L{level}.{ext}",
                            reference_pattern="{scene}_reference.{ext}")
    assert mapped.warnings == [
        f"sponza_atrium_{m}_L1.mp4: read as method 'atrium_{m}' of scene 'sponza'; if "
        "'sponza_atrium' is a scene of its own, its reference is missing (if not, a "
        "--mapping CSV confirms this reading)" for m in ("dlss", "fsr")]


def test_a_lost_reference_is_named_even_when_its_methods_are_nowhere_else(tmp_path):
    """sponza_night's reference was not exported and it alone has xess: its renders were
    method 'night_xess' of sponza with exit 0, no warning, and the suggester proposed that
    mapping. Now the reading is named, and no pattern pair is suggested."""
    names = ["sponza_ref.mkv", "sponza_dlss_q1.mkv", "sponza_dlss_q2.mkv",
             "sponza_night_xess_q1.mkv", "sponza_night_xess_q2.mkv"]
    touch(tmp_path, names)
    mapped = map_by_pattern(tmp_path, test_pattern="{scene}_{method}_q{level}.{ext}",
                            reference_pattern="{scene}_ref.{ext}")
    assert [w.split(":")[0] for w in mapped.warnings] == ["sponza_night_xess_q1.mkv"]
    assert "if 'sponza_night' is a scene of its own, its reference is missing" in \
        mapped.warnings[0]
    hint = suggest_patterns(tmp_path, scan_folder(tmp_path).videos)
    assert hint is not None and hint.doubts == tuple(mapped.warnings)  # never plain advice
    # a method every scene has is not in doubt, separator or not
    other = tmp_path / "two"
    touch(other, ["a_ref.mkv", "a_path_traced_q1.mkv", "b_ref.mkv", "b_path_traced_q1.mkv"])
    assert map_by_pattern(other, test_pattern="{scene}_{method}_q{level}.{ext}",
                          reference_pattern="{scene}_ref.{ext}").warnings == []


def test_a_method_with_the_separator_keeps_it_before_a_setting(tmp_path):
    """'{method}_{setting}' read path_traced_4spp as method 'path', setting 'traced_4spp'."""
    touch(tmp_path, ["bistro/reference.mkv", "bistro/path_traced_4spp_L1.mkv",
                     "bistro/dlss_perf_L2.mkv"])
    mapped = map_by_pattern(tmp_path, test_pattern="{scene}/{method}_{setting}_L{level}.{ext}",
                            reference_pattern="{scene}/reference.{ext}")
    assert not mapped.problems
    assert {(v.method, v.setting, v.level) for v in mapped.videos if v.role == "test"} == {
        ("path_traced", "4spp", 1), ("dlss", "perf", 2)}


def test_methods_that_differ_only_in_case_are_named(tmp_path):
    """sponza_TAA and bistro_taa became two methods without a word."""
    touch(tmp_path, ["sponza_ref.mp4", "sponza_TAA_q1.mp4", "bistro_ref.mp4",
                     "bistro_taa_q1.mp4", "bistro_fsr_q1.mp4", "sponza_fsr_q1.mp4"])
    mapped = map_by_pattern(tmp_path, test_pattern="{scene}_{method}_q{level}.{ext}",
                            reference_pattern="{scene}_ref.{ext}")
    assert mapped.warnings == ["methods 'TAA' and 'taa' differ only in case: they are 2 "
                               "methods of the study; rename the files (or map them in a "
                               "CSV) if they are one"]


def test_a_loose_reference_pattern_leaves_the_test_videos_to_the_test_pattern(tmp_path):
    """'{scene}.{ext}' matches every file: the test videos were all taken as references and
    init said "only references were found"."""
    touch(tmp_path, ["sponza.mp4", "sponza_taa_q1.mp4", "bistro.mp4", "bistro_taa_q2.mp4"])
    mapped = map_by_pattern(tmp_path, test_pattern="{scene}_{method}_q{level}.{ext}",
                            reference_pattern="{scene}.{ext}")
    assert not mapped.problems
    assert truth(mapped) == {("sponza.mp4", "sponza", "reference", None, None),
                             ("bistro.mp4", "bistro", "reference", None, None),
                             ("sponza_taa_q1.mp4", "sponza", "test", "taa", 1),
                             ("bistro_taa_q2.mp4", "bistro", "test", "taa", 2)}


def test_a_stray_copy_is_named_beside_the_suggestion(tmp_path, capsys):
    """A browser's duplicate 'sponza_TAA_q1 (1).mp4' hid the suggestion for the other files;
    now they get it, and the stray is named as left out."""
    renders = tmp_path / "renders"
    touch(renders, ["sponza_ref.mp4", "sponza_TAA_q1.mp4", "sponza_TAA_q2.mp4",
                    "sponza_TAA_q1 (1).mp4"])
    hint = suggest_patterns(renders, scan_folder(renders).videos)
    assert hint is not None and hint.left_out == ("sponza_TAA_q1 (1).mp4",)
    assert (hint.reference_pattern, hint.test_pattern) == ("{scene}_ref.{ext}",
                                                           "{scene}_{method}_q{level}.{ext}")
    code, _, err = init(capsys, renders, "--out", tmp_path / "study")
    assert code == 2 and "these patterns map 3 of 4, leaving out sponza_TAA_q1 (1).mp4" in err


def test_per_method_folders_read_as_scenes_get_the_per_method_patterns(tmp_path, capsys):
    """reference/bistro.mkv and dlss/bistro_L1.mkv: the defaults read 'dlss' as a scene
    without a reference; init now offers the per-method pair, which maps every file."""
    renders = tmp_path / "renders"
    names = ["reference/bistro.mkv", "reference/sponza.mkv", "dlss/bistro_L1.mkv",
             "dlss/sponza_L2.mkv", "fsr/bistro_L1.mkv", "fsr/sponza_L1.mkv"]
    for i, name in enumerate(names):
        write_video(renders / name, np.full((4, 16, 16, 3), 40 * i, np.uint8), 10)
    code, out, err = init(capsys, renders, "--out", tmp_path / "study")
    flags = ("--reference-pattern 'reference/{scene}.{ext}' "
             "--pattern '{method}/{scene}_L{level}.{ext}'")
    assert code == 2 and "missing reference" in out
    assert f"these patterns map all 6 (2 scene(s)): {flags}" in err
    code, _, err = init(capsys, renders, "--out", tmp_path / "study",
                        "--reference-pattern", "reference/{scene}.{ext}",
                        "--pattern", "{method}/{scene}_L{level}.{ext}")
    assert code == 0, err
    ids = {s.id for s in load_manifest(tmp_path / "study" / "manifest.json").manifest.stimuli()}
    assert ids == {"bistro", "sponza", "bistro_dlss_L1", "sponza_dlss_L2", "bistro_fsr_L1",
                   "sponza_fsr_L1"}


def test_a_pair_in_doubt_is_offered_only_with_its_doubt(tmp_path, capsys):
    """sponza_atrium lost its reference: the pair that maps every file would make its videos
    methods of sponza. The error gives the pair with that doubt, not as plain advice, and
    not the generic "give patterns" (which hid the likely missing reference)."""
    renders = tmp_path / "renders"
    touch(renders, ["sponza_ref.mp4", "sponza_dlss_q1.mp4", "sponza_atrium_dlss_q1.mp4"])
    code, _, err = init(capsys, renders, "--out", tmp_path / "study")
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "these patterns would map all 3 (1 scene(s)): --reference-pattern " \
           "'{scene}_ref.{ext}' --pattern '{scene}_{method}_q{level}.{ext}', but " \
           "sponza_atrium_dlss_q1.mp4: read as method 'atrium_dlss' of scene 'sponza'; if " \
           "'sponza_atrium' is a scene of its own, its reference is missing" in err
    assert "settle that first" in err and "these patterns map all" not in err


def test_pattern_slips_are_named_at_once(tmp_path, capsys):
    """A pattern without its extension, absolute or with '..' got "only references were
    found"; now one line names the slip."""
    touch(tmp_path / "renders", ["a/reference.mkv", "a/dlss_L1.mkv"])
    for pattern, says in (("{scene}/{method}_L{level}", "must end in the file's extension"),
                          ("/abs/{scene}/{method}_L{level}.{ext}", "must be relative"),
                          ("../{scene}/{method}_L{level}.{ext}", "without '..'")):
        code, _, err = init(capsys, tmp_path / "renders", "--out", tmp_path / "study",
                            "--pattern", pattern)
        assert code == 2 and says in err and len(err.strip().splitlines()) == 1, pattern


def test_duplicate_ids_say_how_the_files_were_read(tmp_path):
    """A .mov master beside its .mp4 preview: the duplicate says a literal extension takes
    one set; two files one split reads alike say what each was read as."""
    touch(tmp_path, ["a/reference.mov", "a/reference.mp4", "a/dlss_L1.mov", "a/dlss_L1.mp4"])
    mapped = map_by_pattern(tmp_path, test_pattern="{scene}/{method}_L{level}.{ext}",
                            reference_pattern="{scene}/reference.{ext}")
    dup = [p.detail for p in mapped.problems if p.kind == "duplicate id"]
    assert len(dup) == 2 and all("end the patterns in a literal extension, e.g. --pattern "
                                 "'{scene}/{method}_L{level}.mov'" in d for d in dup)
    only = map_by_pattern(tmp_path, test_pattern="{scene}/{method}_L{level}.mov",
                          reference_pattern="{scene}/reference.mov")
    assert not only.problems and len(only.videos) == 2
    other = tmp_path / "split"
    touch(other, ["a/reference.mkv", "a/path_16spp_L1.mkv", "a/path_4spp_L1.mkv"])
    mapped = map_by_pattern(other, test_pattern="{scene}/{method}_{setting}_L{level}.{ext}",
                            reference_pattern="{scene}/reference.{ext}")
    assert [p.detail.split(" (read as ")[1] for p in mapped.problems
            if p.kind == "duplicate id"] == [
        "method 'path', setting '16spp' and method 'path', setting '4spp')"]


def test_a_link_to_a_scene_folder_does_not_rename_the_scene(tmp_path):
    """'Aaa_current' linking to 'sponza' sorted first and became the scene's name."""
    touch(tmp_path, ["sponza/reference.mkv", "sponza/dlss_L1.mkv"])
    (tmp_path / "Aaa_current").symlink_to(tmp_path / "sponza", target_is_directory=True)
    mapped = map_by_pattern(tmp_path, test_pattern="{scene}/{method}_L{level}.{ext}",
                            reference_pattern="{scene}/reference.{ext}")
    assert {v.scene for v in mapped.videos} == {"sponza"} and not mapped.problems


def test_a_scene_named_twice_in_each_path_maps_and_is_suggested(tmp_path):
    """scene01/scene01_dlss_q1.mp4: no pattern could say it ({scene} could not repeat), and
    the defaults gave per-scene methods 'scene01_dlss'."""
    touch(tmp_path, ["scene01/scene01_ref.mp4", "scene01/scene01_dlss_q1.mp4",
                     "scene02/scene02_ref.mp4", "scene02/scene02_dlss_q2.mp4"])
    hint = suggest_patterns(tmp_path, scan_folder(tmp_path).videos)
    assert hint is not None and not hint.doubts
    assert (hint.reference_pattern, hint.test_pattern) == ("{scene}/{scene}_ref.{ext}",
                                                           "{scene}/{scene}_{method}_q{level}.{ext}")
    mapped = map_by_pattern(tmp_path, test_pattern=hint.test_pattern,
                            reference_pattern=hint.reference_pattern)
    assert truth(mapped) == {
        ("scene01/scene01_ref.mp4", "scene01", "reference", None, None),
        ("scene02/scene02_ref.mp4", "scene02", "reference", None, None),
        ("scene01/scene01_dlss_q1.mp4", "scene01", "test", "dlss", 1),
        ("scene02/scene02_dlss_q2.mp4", "scene02", "test", "dlss", 2)}
    # the second {scene} must read as the first: a file of another scene's name is left out
    touch(tmp_path, ["scene01/scene02_dlss_q3.mp4"])
    again = map_by_pattern(tmp_path, test_pattern=hint.test_pattern,
                           reference_pattern=hint.reference_pattern)
    assert [p.as_posix() for p in again.unmatched] == ["scene01/scene02_dlss_q3.mp4"]


def test_a_folder_one_level_too_high_is_named(tmp_path, capsys):
    """renders/2024-05-01/scene01/...: nothing maps, and the message said only "give
    patterns"; now it names the folder to run init on."""
    renders = tmp_path / "renders"
    touch(renders, ["2024-05-01/scene01/reference.mp4", "2024-05-01/scene01/dlss_L1.mp4",
                    "2024-05-01/scene02/reference.mp4", "2024-05-01/scene02/dlss_L2.mp4"])
    code, _, err = init(capsys, renders, "--out", tmp_path / "study")
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert f"every video is under 2024-05-01/: run init on {renders / '2024-05-01'}" in err
