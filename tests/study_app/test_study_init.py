"""``cgvq-study init``: a folder of renders (written here with PyAV) becomes a study folder.

The folders hold known content, so every assertion compares with what was written: which
problems exist, which ids, sizes and checksums the manifest must hold, and which frames a
transcoded copy must decode to.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from support.cli import study_init as init
from support.encode import encode

from cgvq_cli.study_cli import main
from session_store.study_folder import load_study
from stimuli_manifests import load_manifest, read_video, sha256_file, write_video
from study_app.study_check import check_study

SIZE = (48, 64)  # height, width
FRAMES = 12
FPS = 30


def clip(seed: int, *, size: tuple[int, int] = SIZE, frames: int = FRAMES) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (frames, *size, 3), dtype=np.uint8)


def make_renders(folder: Path, *, problems: bool) -> dict[str, np.ndarray]:
    """Two scenes, a reference and two methods at two levels each, in the default layout;
    with ``problems``: a condition of the wrong size, a scene without reference and a file
    that is not a video. Returns id -> the frames written."""
    written = {}
    seed = 0
    for scene in ("forest", "city"):
        seed += 1
        written[scene] = clip(seed)
        write_video(folder / scene / "reference.mkv", written[scene], FPS)
        for method in ("dlss", "fsr"):
            for level in (1, 2):
                seed += 1
                written[f"{scene}_{method}_L{level}"] = clip(seed)
                write_video(folder / scene / f"{method}_L{level}.mkv", clip(seed), FPS)
    if problems:
        write_video(folder / "city" / "taa_L1.mkv", clip(99, size=(40, 64)), FPS)
        write_video(folder / "lake" / "dlss_L1.mkv", clip(98), FPS)
        (folder / "forest" / "fsr_L3.mkv").write_bytes(b"this is not a video\n" * 20)
    return written


def tree(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def error_lines(err: str) -> list[str]:
    """stderr without the progress bars (tqdm redraws with carriage returns)."""
    return [line for line in err.replace("\r", "\n").splitlines()
            if line.strip() and "video/s]" not in line]


def problem_rows(out: str) -> list[str]:
    return out.split("problems (", 1)[1].splitlines()[3:-1]


def test_init_lists_every_problem_and_writes_nothing(tmp_path, capsys):
    renders, study = tmp_path / "renders", tmp_path / "study"
    make_renders(renders, problems=True)
    code, out, err = init(capsys, renders, "--out", study)
    assert code == 2
    rows = problem_rows(out)
    assert len(rows) == 3, out
    joined = "\n".join(rows)
    assert "missing reference" in joined and "lake" in joined
    assert "undecodable" in joined and "forest/fsr_L3.mkv" in joined
    assert "mismatch" in joined and "city/taa_L1.mkv" in joined and "64x40" in joined
    assert "3 problem(s): nothing was written" in out
    assert not study.exists()
    # the probe table names every mapped file with what was written
    assert "city/taa_L1.mkv" in out and "UNDECODABLE" in out
    assert "Traceback" not in err


def test_init_writes_a_study_that_check_accepts_and_reruns_report_changes(tmp_path, capsys):
    renders, study = tmp_path / "renders", tmp_path / "study"
    written = make_renders(renders, problems=False)
    (renders / "forest" / "take2.mkv").write_bytes(b"")  # matches no pattern: a warning
    code, out, _ = init(capsys, renders, "--out", study, "--study-id", "own-renders")
    assert code == 0, out
    assert "take2.mkv" in out and "matches no pattern" in out

    loaded = load_manifest(study / "manifest.json")
    m = loaded.manifest
    assert m.study_id == "own-renders"
    assert sorted(r.id for r in m.references) == ["city", "forest"]
    assert sorted(c.id for c in m.conditions) == sorted(k for k in written if "_" in k)
    for cond in m.conditions:
        scene, method, level = cond.id.split("_")
        assert (cond.reference, cond.method, cond.level) == (scene, method, int(level[1:]))
        assert cond.path == f"videos/{scene}/{method}_{level}.mkv"
        # an exact copy: the checksum is the source file's, the frames are what was written
        assert cond.sha256 == sha256_file(renders / scene / f"{method}_{level}.mkv")
        assert np.array_equal(read_video(study / cond.path), written[cond.id])
    ref = m.reference_by_id("city")
    assert (ref.width, ref.height, ref.frames, ref.fps) == (SIZE[1], SIZE[0], FRAMES, FPS)
    result = check_study(load_study(study))
    assert result.ok, result.errors
    assert result.n_stimuli == len(written)

    # re-run on the same folder: nothing changes, not even the manifest's bytes
    before = tree(study)
    code, out, _ = init(capsys, renders, "--out", study)
    assert code == 0 and "no changes" in out
    assert tree(study) == before

    # an experimenter's edit of the settings survives a re-run that changes stimuli
    data = json.loads((study / "manifest.json").read_text())
    data["protocol"]["repetitions"] = 2
    data["title"] = "My study"
    (study / "manifest.json").write_text(json.dumps(data))
    write_video(renders / "city" / "taa_L1.mkv", clip(50), FPS)         # added
    (renders / "forest" / "dlss_L2.mkv").unlink()                       # removed
    write_video(renders / "city" / "fsr_L1.mkv", clip(51), FPS)         # replaced
    code, out, _ = init(capsys, renders, "--out", study)
    assert code == 0, out
    assert "added: city_taa_L1" in out
    assert "removed: forest_dlss_L2" in out
    assert "replaced (new file or content): city_fsr_L1" in out
    # a pilot run before the change is refused by the analysis from now on: init says so
    assert "sessions run before this change (a pilot's, say) were run on the previous " \
        "manifest: the analysis refuses them, so pilot again" in out
    assert not (study / "videos" / "forest" / "dlss_L2.mkv").exists()
    m = load_manifest(study / "manifest.json").manifest
    assert m.protocol.repetitions == 2 and m.title == "My study"
    assert np.array_equal(read_video(study / "videos/city/fsr_L1.mkv"), clip(51))
    assert check_study(load_study(study)).ok


def test_init_from_a_csv_mapping(tmp_path, capsys):
    renders, study = tmp_path / "renders", tmp_path / "study"
    write_video(renders / "gt_bistro.mkv", clip(1), FPS)
    write_video(renders / "bistro_ours_4spp.mkv", clip(2), FPS)
    write_video(renders / "bistro_base_4spp.mkv", clip(3), FPS)
    mapping = tmp_path / "mapping.csv"
    with open(mapping, "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(["path", "scene", "role", "method", "level", "setting"])
        writer.writerow(["gt_bistro.mkv", "bistro", "reference", "", "", ""])
        writer.writerow(["bistro_ours_4spp.mkv", "bistro", "test", "ours", "1", "4 spp"])
        writer.writerow(["bistro_base_4spp.mkv", "bistro", "test", "base", "1", "4 spp"])
    code, out, _ = init(capsys, renders, "--out", study, "--mapping", mapping)
    assert code == 0, out
    m = load_manifest(study / "manifest.json").manifest
    conds = {c.id: c for c in m.conditions}
    assert set(conds) == {"bistro_ours_L1", "bistro_base_L1"}
    assert conds["bistro_ours_L1"].setting == "4 spp"
    assert conds["bistro_ours_L1"].metadata["source"]["path"] == "bistro_ours_4spp.mkv"
    assert [r.id for r in m.references] == ["bistro"]
    assert check_study(load_study(study)).ok

    # a CSV with problems: every row's problem is listed, the study is left as it was
    with open(mapping, "a", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(["missing.mkv", "bistro", "test", "ours", "2", ""])
        writer.writerow(["bistro_base_4spp.mkv", "bistro", "judge", "", "", ""])
        writer.writerow(["bistro_ours_4spp.mkv", "bistro", "test", "ours", "1", "again"])
    before = tree(study)
    code, out, _ = init(capsys, renders, "--out", study, "--mapping", mapping)
    assert code == 2
    rows = "\n".join(problem_rows(out))
    assert "missing.mkv does not exist" in rows
    assert "'judge' is not 'reference' or 'test'" in rows
    assert "duplicate id" in rows and "bistro_ours_L1" in rows
    assert tree(study) == before


def test_transcode_writes_exact_player_ready_copies(tmp_path, capsys):
    renders, study = tmp_path / "renders", tmp_path / "study"
    scene = renders / "bistro"
    scene.mkdir(parents=True)
    # a lossy source: the copy must hold exactly the frames the source decodes to
    encode(scene / "reference.mp4", clip(7), codec="libx264", pix_fmt="yuv420p", rate=FPS)
    write_video(scene / "blur_L1.mkv", clip(8), FPS)
    code, out, _ = init(capsys, renders, "--out", study, "--transcode")
    assert code == 0, out
    m = load_manifest(study / "manifest.json").manifest
    ref, cond = m.references[0], m.conditions[0]
    assert ref.path == "videos/bistro/reference.avi" and cond.path == "videos/bistro/blur_L1.avi"
    assert ref.metadata["source"] == {"path": "bistro/reference.mp4",
                                      "sha256": sha256_file(scene / "reference.mp4"),
                                      "transcoded": "utvideo"}
    assert np.array_equal(read_video(study / ref.path), read_video(scene / "reference.mp4"))
    assert np.array_equal(read_video(study / cond.path), clip(8))
    assert ref.sha256 == sha256_file(study / ref.path)
    assert check_study(load_study(study)).ok
    assert "transcoded copies decode at" in out
    # unchanged sources are not transcoded again
    mtime = (study / ref.path).stat().st_mtime_ns
    code, out, _ = init(capsys, renders, "--out", study, "--transcode")
    assert code == 0 and "no changes" in out
    assert (study / ref.path).stat().st_mtime_ns == mtime


def test_videos_the_player_cannot_show_are_problems(tmp_path, capsys):
    renders, study = tmp_path / "renders", tmp_path / "study"
    write_video(renders / "big" / "reference.mkv", clip(1, size=(48, 96)), FPS)
    write_video(renders / "big" / "x_L1.mkv", clip(2, size=(48, 96)), FPS)
    write_video(renders / "fast" / "reference.mkv", clip(3), 120)
    write_video(renders / "fast" / "x_L1.mkv", clip(4), 120)
    code, out, _ = init(capsys, renders, "--out", study, "--min-display", "80x600",
                        "--min-refresh-hz", "59")
    assert code == 2
    rows = "\n".join(problem_rows(out))
    assert rows.count("does not fit the minimum display 80x600") == 2
    assert rows.count("120 fps is faster than the minimum refresh rate 59 Hz") == 2
    assert not study.exists()


def test_a_study_with_sessions_is_not_changed_under_them(tmp_path, capsys):
    renders, study = tmp_path / "renders", tmp_path / "study"
    make_renders(renders, problems=False)
    assert init(capsys, renders, "--out", study)[0] == 0
    (study / "sessions").mkdir()
    (study / "sessions" / "P01.sqlite").write_bytes(b"x")
    write_video(renders / "city" / "fsr_L1.mkv", clip(77), FPS)
    code, _, err = init(capsys, renders, "--out", study)
    assert code == 2
    assert len(error_lines(err)) == 1 and "1 session file(s)" in err
    code, out, _ = init(capsys, renders, "--out", study, "--force")
    assert code == 0  # forced: the session left behind is named, to be moved out
    assert f"in {study / 'sessions'}: P01.sqlite (move them out)" in out


def test_a_served_study_is_not_changed_under_its_participants(tmp_path, capsys):
    """Only STUDY/sessions was looked at; a served study's sessions are in the server's
    state, and its participants download the files init would replace."""
    renders, study = tmp_path / "renders", tmp_path / "study"
    make_renders(renders, problems=False)
    assert init(capsys, renders, "--out", study)[0] == 0
    (study / "server").mkdir()
    (study / "server" / "state.sqlite").write_bytes(b"x")
    assert init(capsys, renders, "--out", study)[0] == 0  # the same stimuli: fine
    before = tree(study)
    write_video(renders / "city" / "fsr_L1.mkv", clip(77), FPS)
    code, _, err = init(capsys, renders, "--out", study)
    assert code == 2
    assert len(error_lines(err)) == 1 and "is a served study" in err
    assert tree(study) == before
    assert init(capsys, renders, "--out", study, "--force")[0] == 0


@pytest.mark.parametrize(("args", "says"), [
    (["--pattern", "{scene}/{quality}.{ext}"], "unknown placeholder {quality}"),
    (["--pattern", "{scene}/{method}.{ext}"], "needs a {level} placeholder"),
    (["--reference-pattern", "ref.{ext}"], "needs a {scene} placeholder"),
    (["--min-display", "wide"], "--min-display expects WIDTHxHEIGHT"),
    (["--min-refresh-hz", "0"], "--min-refresh-hz must be between 1 and 1000"),
    (["--mapping", "nonexistent.csv"], "cannot read nonexistent.csv"),
    (["--study-id", "my study/1"], "--study-id 'my study/1' may contain only"),
    (["--mapping", "map.csv", "--pattern", "{scene}/{method}_L{level}.{ext}"],
     "--pattern maps files by their names; --mapping lists them in a CSV instead"),
])
def test_bad_options_are_one_line_errors(tmp_path, capsys, args, says):
    renders = tmp_path / "renders"
    make_renders(renders, problems=False)
    code, _, err = init(capsys, renders, "--out", tmp_path / "study", *args)
    assert code == 2
    assert len(error_lines(err)) == 1 and says in err, err


def test_init_refuses_a_folder_without_videos_and_a_foreign_out_folder(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    code, _, err = init(capsys, tmp_path / "empty", "--out", tmp_path / "study")
    assert code == 2 and "no videos matching" in err
    renders, other = tmp_path / "renders", tmp_path / "other"
    make_renders(renders, problems=False)
    other.mkdir()
    (other / "thesis.tex").write_text("precious")
    code, _, err = init(capsys, renders, "--out", other)
    assert code == 2 and "is not empty and holds no manifest.json" in err
    assert [p.name for p in other.iterdir()] == ["thesis.tex"]


@pytest.mark.parametrize("out", ["notes.txt", "notes.txt/study"])
def test_init_refuses_an_out_that_is_or_lies_under_a_file(tmp_path, capsys, out):
    renders = tmp_path / "renders"
    make_renders(renders, problems=False)
    (tmp_path / "notes.txt").write_text("precious")
    code, stdout, err = init(capsys, renders, "--out", tmp_path / out)
    assert code == 2 and len(error_lines(err)) == 1, err
    assert "notes.txt is a file; give a folder for the study" in err
    assert stdout == ""  # refused before any video was probed
    assert (tmp_path / "notes.txt").read_text() == "precious"


def test_init_refuses_a_folder_with_references_only(tmp_path, capsys):
    renders, study = tmp_path / "renders", tmp_path / "study"
    write_video(renders / "forest" / "reference.mkv", clip(1), FPS)
    code, out, err = init(capsys, renders, "--out", study)
    assert code == 2
    assert len(error_lines(err)) == 1 and "cgvq-study init: error:" in err
    assert "a study needs at least one test video" in err
    assert "no test videos" in out
    assert not study.exists()


def test_check_refuses_a_manifest_without_conditions(tmp_path, capsys):
    renders, study = tmp_path / "renders", tmp_path / "study"
    make_renders(renders, problems=False)
    assert init(capsys, renders, "--out", study)[0] == 0
    data = json.loads((study / "manifest.json").read_text())
    data["conditions"] = []
    data["protocol"]["repetitions"] = 1
    (study / "manifest.json").write_text(json.dumps(data))
    code = main(["check", str(study)])
    out, err = capsys.readouterr()
    assert code == 2
    assert "OK" not in out
    assert len(error_lines(err)) == 1 and "no test conditions" in err, err


def test_a_render_named_otherwise_leaves_an_unbalanced_design_that_is_named(tmp_path, capsys):
    """``fsr-L2.mkv`` among ``fsr_L2.mkv``: left out with one line, and check said "ready"
    for a study whose fsr L2 rests on one scene of two."""
    renders, study = tmp_path / "renders", tmp_path / "study"
    make_renders(renders, problems=False)
    (renders / "city" / "fsr_L2.mkv").rename(renders / "city" / "fsr-L2.mkv")
    code, out, _ = init(capsys, renders, "--out", study)
    assert code == 0, out
    said = [ln for ln in out.splitlines() if "method 'fsr' level 2 is in" in ln]
    assert len(said) == 1 and "1 of 2 scenes (missing in city)" in said[0]
    assert said[0].endswith("a file left out may be it: city/fsr-L2.mkv")
    assert not any("dlss" in ln and "scenes (missing" in ln for ln in out.splitlines())
    result = check_study(load_study(study))
    assert result.ok and [w for w in result.warnings
                          if "method 'fsr' level 2 is in 1 of 2 scenes" in w]
    assert main(["check", str(study)]) == 0
    assert "  warning: method 'fsr' level 2 is in 1 of 2 scenes" in capsys.readouterr().out
