"""Same seed, same bytes; the command line reports user errors in one line."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from study_app.synth import SynthOptions, synthesize


def _tree_bytes(root):
    return {p.relative_to(root).as_posix(): p.read_bytes()
            for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.mark.slow  # about 7 s here: CI runs it after `make test` (.ci/run)
def test_same_seed_same_bytes_other_seed_other_noise(egl, tmp_path, tiny_study, tiny_options):
    opts = SynthOptions(**tiny_options)
    again = synthesize(tmp_path / "again", opts, progress=False)
    first, second = _tree_bytes(tiny_study.parent), _tree_bytes(again.parent)
    assert first.keys() == second.keys()
    assert len(first) == 1 + 4 + 48
    for name in first:
        assert first[name] == second[name], name

    other = synthesize(tmp_path / "other",
                       SynthOptions(**{**tiny_options, "seed": tiny_options["seed"] + 1,
                                       "scenes": ("colonnade",),
                                       "methods": ("path_tracing", "splatting")}),
                       progress=False)
    third = _tree_bytes(other.parent)
    # the reference has no randomness; Monte Carlo noise and splat placement follow the seed
    v = "videos/colonnade/"
    assert third[v + "reference_30fps.mkv"] == first[v + "reference_30fps.mkv"]
    assert third[v + "path_tracing_L1.mkv"] != first[v + "path_tracing_L1.mkv"]
    assert third[v + "splatting_L1.mkv"] != first[v + "splatting_L1.mkv"]
    # same options, same videos, same study id; other videos, another id (the analysis
    # tells studies apart by it)
    ids = [json.loads((d / "manifest.json").read_text())["study_id"]
           for d in (tiny_study.parent, again.parent, other.parent)]
    assert ids[0] == ids[1] != ids[2] and ids[0].startswith("synthetic-cg-")
    assert SynthOptions(**{**tiny_options, "study_id": "mine"}).resolved_study_id() == "mine"


def test_existing_study_is_not_overwritten_silently(egl, tiny_study):
    from session_store.errors import StudyError

    with pytest.raises(StudyError, match="--overwrite"):
        synthesize(tiny_study.parent, SynthOptions(width=16, height=16, seconds=0.1,
                                                   methods=("vrs",)), progress=False)


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "cgvq_cli.study_cli", *args],
                          capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize(
    "args, message",
    [
        (["--size", "30"], "multiples of 8"),
        (["--methods", "raytracing"], "unknown method"),
        (["--scenes", "nowhere"], "unknown scene"),
        (["--seconds", "0.01"], "whole number of frames"),
        (["--size", "800000"], "at most 8192"),
        (["--size", "16384x16"], "at most 8192"),
        (["--size", "8"], "at least 16"),
        (["--seconds", "1e9"], "at most 60 seconds"),
        (["--methods", ""], "--methods is empty"),
        (["--methods", ","], "--methods is empty"),
        (["--scenes", "colonnade,colonnade"], "more than once"),
    ],
)
def test_cli_user_errors_are_one_line_exit_2(tmp_path, args, message):
    res = _cli("synth", "--out", str(tmp_path / "s"), "--no-progress", *args)
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], res.stderr
    assert "Traceback" not in res.stderr
    assert not (tmp_path / "s").exists()


def _failing_render(*_args, **_kwargs):
    import moderngl

    raise moderngl.Error("the framebuffer is not complete")


def test_render_failure_is_a_study_error_and_leaves_no_folder(egl, tmp_path, monkeypatch):
    from session_store.errors import StudyError
    from study_app.synth import build

    monkeypatch.setattr(build, "_render_scene", _failing_render)
    out = tmp_path / "new" / "study"
    with pytest.raises(StudyError, match="smaller --size"):
        synthesize(out, SynthOptions(width=16, height=16, seconds=0.1, methods=("vrs",),
                                     scenes=("colonnade",)), progress=False)
    assert not (tmp_path / "new").exists()


def test_render_failure_keeps_the_study_being_overwritten(egl, tmp_path, monkeypatch):
    from session_store.errors import StudyError
    from study_app.synth import build

    out = tmp_path / "study"
    (out / "videos").mkdir(parents=True)
    (out / "manifest.json").write_text("{}")
    monkeypatch.setattr(build, "_render_scene", _failing_render)
    with pytest.raises(StudyError, match="OpenGL driver"):
        synthesize(out, SynthOptions(width=16, height=16, seconds=0.1, methods=("vrs",),
                                     scenes=("colonnade",)), overwrite=True, progress=False)
    assert sorted(p.name for p in out.iterdir()) == ["manifest.json", "videos"]
    assert (out / "manifest.json").read_text() == "{}"


def test_more_frames_than_memory_is_refused_before_anything(tmp_path, monkeypatch):
    from session_store.errors import StudyError
    from study_app.synth import build

    monkeypatch.setattr(build, "available_memory_bytes", lambda: 1024**2)
    with pytest.raises(StudyError, match="memory is available"):
        synthesize(tmp_path / "s", SynthOptions(width=512, height=512, seconds=10,
                                                methods=("vrs",)), progress=False)
    assert not (tmp_path / "s").exists()


def test_cli_writes_a_study(egl, tmp_path):
    out = tmp_path / "s"
    res = _cli("synth", "--out", str(out), "--size", "32x24", "--seconds", "0.1",
               "--scenes", "lattice", "--methods", "vrs,frame_interpolation", "--no-progress")
    assert res.returncode == 0, res.stderr
    from stimuli_manifests import load_manifest, probe_video

    loaded = load_manifest(out / "manifest.json")
    methods = [c.method for c in loaded.manifest.conditions]
    assert methods == ["frame_interpolation"] * 4 + ["vrs"] * 4
    info = probe_video(loaded.resolve(loaded.manifest.conditions[0].path))
    assert (info.width, info.height, info.frame_count, info.fps) == (32, 24, 6, 60.0)
