"""A mapping CSV as a spreadsheet saves it maps as the researcher wrote it."""

from __future__ import annotations

from pathlib import Path

from stimuli_manifests.from_folder.mapping import map_by_csv


def test_a_mapping_csv_saved_by_a_spreadsheet_maps_as_written(tmp_path: Path):
    """Capitalised headers, empty trailing columns, blank rows, a level re-saved as 1.0 and
    a reference called GT were refused with misleading messages."""
    for name in ("gt/bistro.mkv", "ours/bistro_a.mkv", "ours/bistro_b.mkv"):
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_bytes(b"")
    table = tmp_path / "map.csv"
    table.write_text("Path;Scene;Role;Method;Level;Setting;;\n"
                     "gt/bistro.mkv;bistro;GT;;;;;\n"
                     ";;;;;;;\n"
                     "ours/bistro_a.mkv;bistro;Test;ours;1.0;4 spp;;\n"
                     "\n"
                     "ours/bistro_b.mkv;bistro;test;ours;2;;;\n", encoding="utf-8")
    mapped = map_by_csv(tmp_path, table)
    assert mapped.problems == []
    assert {(v.path.as_posix(), v.role, v.method, v.level, v.setting) for v in mapped.videos} \
        == {("gt/bistro.mkv", "reference", None, None, None),
            ("ours/bistro_a.mkv", "test", "ours", 1, "4 spp"),
            ("ours/bistro_b.mkv", "test", "ours", 2, None)}
    table.write_text("path,scene,role,method,level\nours/bistro_a.mkv,bistro,test,ours,1.5\n",
                     encoding="utf-8")
    assert "whole-number level" in str(map_by_csv(tmp_path, table).problems[0])
