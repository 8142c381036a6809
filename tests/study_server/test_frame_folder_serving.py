"""A stimulus that is a folder of PNG frames is served as its frames only: a note or a
``.DS_Store`` beside them stays on the experimenter's disk, and a folder the player could not
read is refused when the study is served, not when a participant downloads it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from session_store.errors import StudyError
from study_server.study_files import FileHashes, build_version

from .conftest import make_served_study


def _study_with_frame_folder(tmp_path: Path, names: list[str]) -> Path:
    folder = make_served_study(tmp_path / "study", refs=1, conds=1)
    frames = folder / "videos" / "ref0_frames"
    frames.mkdir()
    for name in names:
        (frames / name).write_bytes(name.encode())
    manifest = json.loads((folder / "manifest.json").read_text(encoding="utf-8"))
    ref = manifest["references"][0]
    ref["path"] = "ref0_frames"
    ref.pop("sha256", None)
    (folder / "manifest.json").write_text(json.dumps(manifest), encoding="utf-8")
    return folder


def _served(folder: Path) -> set[str]:
    version = build_version(folder, (folder / "manifest.json").read_bytes(), FileHashes(),
                            from_disk=True)
    return {f.path for f in version.files}


def test_frame_folder_serves_exactly_its_numbered_frames(tmp_path):
    folder = _study_with_frame_folder(
        tmp_path, ["frame_1.png", "frame_2.png", "frame_3.png", "notes.txt", ".DS_Store",
                   "render.log"])
    served = _served(folder)
    assert {p for p in served if p.startswith("videos/ref0_frames/")} == {
        "videos/ref0_frames/frame_1.png", "videos/ref0_frames/frame_2.png",
        "videos/ref0_frames/frame_3.png"}


@pytest.mark.parametrize("names, words", [
    (["frame_1.png", "frame_3.png"], "missing"),
    (["notes.txt"], "no .png frames"),
])
def test_unreadable_frame_folder_is_refused_when_served(tmp_path, names, words):
    folder = _study_with_frame_folder(tmp_path, names)
    with pytest.raises(StudyError, match=words) as exc:
        _served(folder)
    assert str(exc.value).startswith("SRC01: ")
