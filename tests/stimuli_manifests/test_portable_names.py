"""Names every participant's download refuses (a Windows device name, a ':' or a trailing
dot) are refused where the study is made and checked, not when the first participant
starts: init names the folder or file, a manifest holding one does not load, and the
download's rule is the same function."""

from __future__ import annotations

from pathlib import Path

import pytest

from stimuli_manifests.errors import ManifestError
from stimuli_manifests.from_folder.mapping import map_by_pattern
from stimuli_manifests.paths import check_relative, portable_part_problem
from study_app.remote.download import _safe_relative

REFUSED = ["aux", "AUX.mp4", "com1", "nul.txt", "a:b", "scene.", "scene ", "x?y", 'q"t',
           "a|b", "a<b", "tab\there"]
KEPT = ["auxiliary", "sponza", "lpt", "con_artist.mp4", "v1.2", "scene-01", "été"]


@pytest.mark.parametrize("name", REFUSED)
def test_a_name_the_download_refuses_is_refused_by_the_manifest_too(name):
    assert portable_part_problem(name) is not None
    with pytest.raises(ManifestError, match="download refuses it, so rename it"):
        check_relative(f"videos/{name}/ref.mkv", field="references[0].path")
    with pytest.raises(Exception, match="characters a file name cannot hold"):
        _safe_relative(f"videos/{name}/ref.mkv")


@pytest.mark.parametrize("name", KEPT)
def test_ordinary_names_pass_both(name):
    assert portable_part_problem(name) is None
    assert check_relative(f"videos/{name}/ref.mkv", field="f").parts[1] == name
    assert _safe_relative(f"videos/{name}/ref.mkv") == f"videos/{name}/ref.mkv"


def test_init_names_each_bad_folder_once(tmp_path: Path):
    """A scene folder 'aux' and a file with ':' : one problem each, naming what to rename;
    the good scene maps without one."""
    for name in ("aux/reference.mp4", "aux/dlss_L1.mp4", "aux/fsr_L1.mp4",
                 "bistro/reference.mp4", "bistro/dlss:fast_L1.mp4", "bistro/fsr_L1.mp4"):
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_bytes(b"")
    mapped = map_by_pattern(tmp_path, test_pattern="{scene}/{method}_L{level}.{ext}",
                            reference_pattern="{scene}/reference.{ext}")
    bad = [(p.kind, p.subject, p.detail) for p in mapped.problems if p.kind == "bad name"]
    assert [(w, d.split(";")[0]) for _, w, d in bad] == [
        ("aux/reference.mp4", "folder name 'aux' is a device name Windows reserves"),
        ("bistro/dlss:fast_L1.mp4", "file name 'dlss:fast_L1.mp4' holds ':', which a Windows "
         "file name cannot")]
    assert all("rename the" in d for *_, d in bad)

