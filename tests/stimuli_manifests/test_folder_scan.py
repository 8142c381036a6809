"""One walk of a renders folder finds its videos, broken links and image sequences (a folder
on a network disk was listed three times per ``init``)."""

from __future__ import annotations

import os
from pathlib import PurePosixPath

import stimuli_manifests.from_folder.mapping as mapping


def test_one_walk_finds_videos_broken_links_and_frame_sequences(tmp_path, monkeypatch):
    renders = tmp_path / "renders"
    (renders / "arena" / "frames").mkdir(parents=True)
    for name in ("arena/reference.mp4", "arena/taa_L1.mp4", "arena/notes.txt",
                 "arena/.hidden_L2.mp4", "arena/frames/f.0001.png", "arena/frames/f.0002.png",
                 "lone.0001.png"):
        (renders / name).write_bytes(b"x")
    os.symlink(tmp_path / "gone.mp4", renders / "arena" / "taa_L2.mp4")
    walks: list[str] = []
    real = os.walk

    def counting_walk(top, *args, **kwargs):
        walks.append(str(top))
        return real(top, *args, **kwargs)

    monkeypatch.setattr(mapping.os, "walk", counting_walk)
    out = mapping.map_by_pattern(renders)
    assert len(walks) == 1
    assert sorted(v.path.as_posix() for v in out.videos) == ["arena/reference.mp4",
                                                             "arena/taa_L1.mp4"]
    assert [(p.kind, p.subject) for p in out.problems if p.kind == "broken link"] == [
        ("broken link", "arena/taa_L2.mp4")]
    assert out.frame_sequences == {PurePosixPath("arena/frames"): 2}  # one frame is not one
