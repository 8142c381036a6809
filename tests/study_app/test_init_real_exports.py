"""``cgvq-study init`` on folders as rendering tools export them (findings of the init audit):
flat output folders whose scene names hold the separator, containers beyond the usual few,
image sequences, millisecond timestamps, semicolon CSVs, HDR tags, display options given one at
a time, export slips, and re-runs after hand edits. Each folder is written here with PyAV, so
every assertion compares with what was written."""

from __future__ import annotations

import json
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest
from support.cli import study_init as init
from support.encode import encode

from stimuli_manifests import load_manifest, probe_video, write_video

FPS = 30


def clip(seed: int, frames: int = 8, size: tuple[int, int] = (32, 48)) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (frames, *size, 3), dtype=np.uint8)


def warned(out: str, subject: str, detail: str) -> bool:
    """Whether init's warnings (one line per message, its files in brackets) say ``detail``
    of ``subject``."""
    return any(detail in ln and subject in ln.split(detail, 1)[1]
               for ln in out.splitlines() if ln.strip().startswith("warning:"))


def entries(study: Path) -> dict[str, dict]:
    data = json.loads((study / "manifest.json").read_text())
    return {e["id"]: e for e in [*data["references"], *data["conditions"]]}


def test_a_scene_name_with_the_separator_is_paired_with_its_own_reference(tmp_path, capsys):
    renders = tmp_path / "MovieRenders"
    frames = {"sponza": clip(1), "sponza_atrium": clip(2)}
    for scene, content in frames.items():
        write_video(renders / f"{scene}_reference.mkv", content, FPS)
        write_video(renders / f"{scene}_dlss_L1.mkv", content // 2, FPS)
    code, out, err = init(capsys, renders, "--out", tmp_path / "study",
                          "--pattern", "{scene}_{method}_L{level}.{ext}",
                          "--reference-pattern", "{scene}_reference.{ext}")
    assert code == 0, err
    m = load_manifest(tmp_path / "study" / "manifest.json").manifest
    pairs = {str(c.id): (c.reference, c.method) for c in m.conditions}
    assert pairs == {"sponza_dlss_L1": ("sponza", "dlss"),
                     "sponza_atrium_dlss_L1": ("sponza_atrium", "dlss")}
    assert "has no test video" not in out


def test_more_containers_are_taken_and_frame_folders_are_named(tmp_path, capsys):
    renders = tmp_path / "renders"
    ref = clip(3)
    encode(renders / "arena" / "reference.m2ts", ref, codec="libx264rgb", options={"qp": "0"},
           rate=FPS)
    encode(renders / "arena" / "obs_L1.m2ts", ref // 2, codec="libx264rgb",
           options={"qp": "0"}, rate=FPS)
    frames_dir = renders / "bistro" / "frames"
    frames_dir.mkdir(parents=True)
    from PIL import Image

    for i, frame in enumerate(clip(4)):
        Image.fromarray(frame).save(frames_dir / f"Bistro.{1001 + i:04d}.png")
    code, out, err = init(capsys, renders, "--out", tmp_path / "study")
    assert code == 0, err
    assert set(entries(tmp_path / "study")) == {"arena", "arena_obs_L1"}
    assert warned(out, "bistro/frames/", "8 single frames (an image sequence), left out")


def _ms_capture(path: Path, frames: np.ndarray, fps: float) -> Path:
    """A capture whose timestamps were rounded to milliseconds (an OBS remux)."""
    def ms(stream) -> None:
        stream.codec_context.time_base = Fraction(1, 1000)

    return encode(path, frames, codec="libx264rgb", options={"qp": "0"},
                  rate=Fraction(fps).limit_denominator(1001), time_base=Fraction(1, 1000),
                  pts=[round(i * 1000 / fps) for i in range(len(frames))], setup=ms)


def test_millisecond_timestamps_keep_the_nominal_frame_rate(tmp_path, capsys):
    renders = tmp_path / "renders"
    n = 240  # 4 s at 60 fps: the average rate alone is 60.005
    ref = np.repeat(clip(5, frames=4, size=(16, 16)), n // 4, axis=0)
    write_video(renders / "arena" / "reference.mkv", ref, 60)
    path = _ms_capture(renders / "arena" / "obs_L1.mp4", ref // 2, 60)
    import av

    with av.open(str(path)) as c:
        assert c.streams.video[0].average_rate != 60  # the rounding is really there
    code, out, err = init(capsys, renders, "--out", tmp_path / "study", "--min-display",
                          "640x480", "--min-refresh-hz", "60")
    assert code == 0, err
    assert probe_video(path).fps == 60  # as the player and the metrics will read it
    # a real difference stays a mismatch: a 59.94 fps capture against the 60 fps render
    _ms_capture(renders / "arena" / "obs_L1.mp4", ref // 2, 60000 / 1001)
    code, out, _ = init(capsys, renders, "--out", tmp_path / "study")
    assert code == 2 and "59.9401 fps differs from its reference" in out


def test_a_semicolon_csv_maps_and_a_latin1_csv_says_save_as_utf8(tmp_path, capsys):
    renders = tmp_path / "renders"
    write_video(renders / "gt.mkv", clip(6), FPS)
    write_video(renders / "ours.mkv", clip(7), FPS)
    table = tmp_path / "map.csv"
    table.write_text("path;scene;role;method;level;setting\ngt.mkv;bistro;reference;;;\n"
                     "ours.mkv;bistro;test;ours;1;4 spp\n", encoding="utf-8")
    code, _, err = init(capsys, renders, "--out", tmp_path / "study", "--mapping", table)
    assert code == 0, err
    assert set(entries(tmp_path / "study")) == {"bistro", "bistro_ours_L1"}
    table.write_bytes("path,scene,role,method,level,setting\ngt.mkv,bistro,reference,,,\n"
                      "ours.mkv,bistro,test,ours,1,réglage\n".encode("latin-1"))
    code, _, err = init(capsys, renders, "--out", tmp_path / "s2", "--mapping", table)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2 and len(lines) == 1 and "save it as 'CSV UTF-8'" in err


def test_an_hdr_export_is_named(tmp_path, capsys):
    renders = tmp_path / "renders"

    def pq(stream) -> None:
        stream.codec_context.color_trc = 16  # SMPTE ST 2084
        stream.codec_context.color_primaries = 9  # BT.2020

    for name, seed in (("reference", 8), ("ue_L1", 9)):
        encode(renders / "hdr" / f"{name}.mkv", clip(seed), codec="ffv1",
               pix_fmt="yuv444p10le", setup=pq)
    code, out, err = init(capsys, renders, "--out", tmp_path / "study")
    assert code == 0, err
    for name in ("hdr/reference.mkv", "hdr/ue_L1.mkv"):
        assert warned(out, name, "HDR video (PQ transfer, SMPTE ST 2084)")


def test_one_display_option_keeps_the_studys_other(tmp_path, capsys):
    renders, study = tmp_path / "renders", tmp_path / "study"
    write_video(renders / "a" / "reference.mkv", clip(10), FPS)
    write_video(renders / "a" / "m_L1.mkv", clip(11), FPS)
    assert init(capsys, renders, "--out", study, "--min-display", "1280x720",
                "--min-refresh-hz", "120")[0] == 0

    def display() -> tuple:
        d = load_manifest(study / "manifest.json").manifest.display
        return d.min_width, d.min_height, d.min_refresh_hz

    code, out, _ = init(capsys, renders, "--out", study, "--min-refresh-hz", "144")
    assert code == 0 and display() == (1280, 720, 144)
    assert "display now needs at least 1280x720 pixels at 144 Hz" in out
    assert init(capsys, renders, "--out", study, "--min-display", "1366x768")[0] == 0
    assert display() == (1366, 768, 144)


def test_export_slips_are_warned_of(tmp_path, capsys):
    renders = tmp_path / "renders"
    ref = clip(12)
    write_video(renders / "a" / "reference.mkv", ref, FPS)
    write_video(renders / "a" / "m_L1.mkv", clip(13), FPS)
    (renders / "a" / "m_L2.mkv").write_bytes((renders / "a" / "m_L1.mkv").read_bytes())
    (renders / "a" / "m_L3.mkv").write_bytes((renders / "a" / "reference.mkv").read_bytes())
    write_video(renders / "b" / "reference.mkv", clip(14), FPS)
    write_video(renders / "b" / "m-L1.mkv", clip(15), FPS)  # a typo: matches no pattern
    code, out, err = init(capsys, renders, "--out", tmp_path / "study")
    assert code == 0, err
    assert warned(out, "a/m_L2.mkv", "the same file as a/m_L1.mkv (byte for byte)")
    assert warned(out, "a/m_L3.mkv", "the same file as its reference a/reference.mkv")
    assert warned(out, "b/reference.mkv", "the reference of scene 'b' has no test video")
    assert "scene 'a' has no test video" not in out


def test_every_problem_comes_in_one_run_case_collisions_included(tmp_path, capsys):
    renders = tmp_path / "renders"
    for scene in ("bistro", "Bistro"):
        write_video(renders / scene / "reference.mkv", clip(16), FPS)
        write_video(renders / scene / "m_L1.mkv", clip(17), FPS)
    write_video(renders / "lake" / "m_L1.mkv", clip(18), FPS)  # no reference
    code, out, _ = init(capsys, renders, "--out", tmp_path / "study")
    assert code == 2
    assert "missing reference" in out and out.count("shared file") == 2


def test_a_turned_video_is_not_called_undecodable(tmp_path, capsys):
    renders = tmp_path / "renders"
    ref = clip(19)
    encode(renders / "rot" / "reference.mp4", ref, codec="libx264rgb", options={"qp": "0"})
    encode(renders / "rot" / "cam_L1.mp4", ref, codec="libx264rgb", options={"qp": "0"},
           setup=lambda s: s.set_display_rotation(90))
    code, out, _ = init(capsys, renders, "--out", tmp_path / "study")
    assert code == 2
    row = next(ln for ln in out.splitlines() if "rot/cam_L1.mp4" in ln and "matrix" in ln)
    assert "not as stored" in row and "undecodable" not in row and "cannot be decoded" not in row
    assert row.rstrip().endswith("(FFmpeg applies the matrix when it re-encodes)")  # not cut


def test_a_transcode_neither_repeats_its_advice_nor_logs_warnings(tmp_path, capsys):
    renders = tmp_path / "renders"
    for name, seed in (("reference", 20), ("m_L1", 21)):
        encode(renders / "a" / f"{name}.mkv", clip(seed), codec="ffv1", pix_fmt="yuv444p10le")
    code, out, err = init(capsys, renders, "--out", tmp_path / "study", "--transcode")
    assert code == 0, err
    assert "10-bit (yuv444p10le); its copy holds 8-bit RGB" in out
    assert "init --transcode stores" not in out and "WARNING" not in err


@pytest.mark.parametrize("edit", ["delete", "edit"])
def test_a_rerun_restores_a_copy_changed_by_hand_and_says_so(tmp_path, capsys, edit):
    renders, study = tmp_path / "renders", tmp_path / "study"
    for scene, seed in (("a", 22), ("b", 24)):
        write_video(renders / scene / "reference.mkv", clip(seed), FPS)
        write_video(renders / scene / "m_L1.mkv", clip(seed + 1), FPS)
    assert init(capsys, renders, "--out", study)[0] == 0
    copy = study / "videos" / "a" / "m_L1.mkv"
    original = copy.read_bytes()
    if edit == "delete":
        copy.unlink()
    else:
        copy.write_bytes(original[:-10] + b"\0" * 10)
    code, out, _ = init(capsys, renders, "--out", study)
    assert code == 0 and copy.read_bytes() == original
    assert "copied again (the study's copy was missing or edited): a_m_L1" in out
    # a scene removed from the renders leaves no empty folder behind
    for f in (renders / "b").iterdir():
        f.unlink()
    (renders / "b").rmdir()
    code, out, _ = init(capsys, renders, "--out", study)
    assert code == 0 and "removed: b, b_m_L1" in out
    assert not (study / "videos" / "b").exists() and (study / "videos" / "a").is_dir()


@pytest.mark.parametrize("name", ["Reference.mp4", "REF.mp4", "sponza_GT.mp4",
                                  "original.mp4"])
def test_a_missing_reference_names_the_file_that_looks_like_it(tmp_path, name):
    from stimuli_manifests.from_folder.mapping import map_by_pattern

    for rel in (f"sponza/{name}", "sponza/dlss_L1.mp4", "sponza/fsr_L2.mp4",
                "bistro/reference.mp4", "bistro/dlss_L1.mp4", "bistro/notes_final.mp4"):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_bytes(b"x")
    problems = map_by_pattern(tmp_path).problems
    assert [p.kind for p in problems] == ["missing reference"], problems
    detail = problems[0].detail
    assert f"did you mean sponza/{name}?" in detail and "--reference-pattern" in detail
    assert "notes_final" not in detail


def test_a_csv_mapping_names_the_unlisted_file_that_looks_like_the_reference(tmp_path):
    from stimuli_manifests.from_folder.mapping import map_by_csv

    for rel in ("sponza/Reference.mp4", "sponza/dlss_L1.mp4", "sponza/other.mp4"):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_bytes(b"x")
    table = tmp_path / "map.csv"
    table.write_text("path,scene,role,method,level\nsponza/dlss_L1.mp4,sponza,test,dlss,1\n")
    (problem,) = map_by_csv(tmp_path, table).problems
    assert "did you mean sponza/Reference.mp4? It is not in map.csv" in problem.detail
    assert "other.mp4" not in problem.detail


@pytest.mark.parametrize("sep", [",", ";", "\t"])
def test_a_mapping_csv_keeps_excel_quoting_whatever_its_delimiter(tmp_path, sep):
    """Excel writes a quote inside a quoted field doubled: one quote, as before the
    delimiter was guessed (the guessed dialect kept both)."""
    from stimuli_manifests.from_folder.mapping import map_by_csv

    for name in ("gt.mkv", "ours.mkv"):
        (tmp_path / name).write_bytes(b"x")
    table = tmp_path / "map.csv"
    rows = [["path", "scene", "role", "method", "level", "setting"],
            ["gt.mkv", "bistro", "reference", "", "", ""],
            ["ours.mkv", "bistro", "test", "ours", "1", '"4 ""spp"", denoised"']]
    table.write_text("\n".join(sep.join(r) for r in rows) + "\n", encoding="utf-8")
    mapping = map_by_csv(tmp_path, table)
    assert not mapping.problems
    assert [v.setting for v in mapping.videos if v.role == "test"] == ['4 "spp", denoised']


def test_a_scene_whose_reference_is_missing_is_not_split_without_a_word(tmp_path):
    """sponza_atrium has no reference: its video is read as method 'atrium_dlss' of sponza,
    and init says so; a method with the separator in every scene ('dlss_q') is not named."""
    from stimuli_manifests.from_folder.mapping import map_by_pattern

    for name in ("sponza_reference", "sponza_dlss_L1", "sponza_dlss_q_L1",
                 "sponza_atrium_dlss_L1", "bistro_reference", "bistro_dlss_L1",
                 "bistro_dlss_q_L1"):
        (tmp_path / f"{name}.mp4").write_bytes(b"x")
    mapping = map_by_pattern(tmp_path, test_pattern="{scene}_{method}_L{level}.{ext}",
                             reference_pattern="{scene}_reference.{ext}")
    assert not mapping.problems
    assert mapping.warnings == [
        "sponza_atrium_dlss_L1.mp4: read as method 'atrium_dlss' of scene 'sponza'; if "
        "'sponza_atrium' is a scene of its own, its reference is missing (if not, a "
        "--mapping CSV confirms this reading)"]


def test_the_seating_distance_is_set_kept_and_removed(tmp_path, capsys):
    renders, study = tmp_path / "renders", tmp_path / "study"
    write_video(renders / "a" / "reference.mkv", clip(10), FPS)
    write_video(renders / "a" / "m_L1.mkv", clip(11), FPS)

    def seat() -> float | None:
        return load_manifest(study / "manifest.json").manifest.protocol.viewing_distance_cm

    code, out, _ = init(capsys, renders, "--out", study, "--viewing-distance", "75")
    assert code == 0 and seat() == 75
    assert "participants are told to sit about 75 cm from the screen" in out
    assert init(capsys, renders, "--out", study, "--min-refresh-hz", "120")[0] == 0
    assert seat() == 75  # another option keeps it
    code, out, _ = init(capsys, renders, "--out", study, "--viewing-distance", "0")
    assert code == 0 and seat() is None and "participants are not told where to sit" in out
    for bad in ("20", "nan", "500"):
        code, _, err = init(capsys, renders, "--out", study, "--viewing-distance", bad)
        assert code == 2 and "--viewing-distance must be 30 to 200 cm" in err, err
