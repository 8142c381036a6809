"""A failed colour-vision check with ``on_fail: end`` closes the session politely: the real
app under Xvfb, both protan plates misread on purpose."""

from __future__ import annotations

import json

import pytest
from support.studies import make_study

from session_store import read_session
from stimuli_manifests import fill_checksums, load_manifest, parse_manifest, save_manifest
from stimuli_manifests.panel_templates import default_panel
from study_app.vision.isochromatic import plate_series

pytestmark = pytest.mark.gui


@pytest.mark.slow  # about 18 s: CI runs it after `make test` (.ci/run), as does `make test-slow`
def test_a_failed_check_ends_the_session_when_the_study_says_so(tmp_path, xdisplay,
                                                                app_driver):
    study = make_study(tmp_path / "study", min_display=(640, 480))
    path = study / "manifest.json"
    data = json.loads(path.read_text())
    panel = default_panel()
    panel["vision_screening"]["on_fail"] = "end"
    data["panel"] = panel
    save_manifest(parse_manifest(data), path)
    save_manifest(fill_checksums(load_manifest(path)), path)
    app = app_driver(xdisplay, [str(study), "--participant", "P01", "--seed", "3",
                                "--practice", "0", "--pilot-no-vsync"])
    app.wait("preflight-passed")
    app.key("space")
    app.wait("welcome")
    app.key("space")
    app.wait("consent")
    app.key("a")
    app.wait("colour-check")
    app.key("space")
    for k, plate in enumerate(plate_series(3), start=1):
        app.wait(f"colour-plate index={k}")
        app.key("n" if plate.kind == "protan" else plate.answer, "Return")
    app.wait("finishing screened_out=1")
    app.wait("end")  # the end screen takes keys once it says so
    app.key("Return")
    code, out = app.finish()
    assert code == 0 and "ended after the colour-vision check" in out
    record = read_session(study / "sessions" / "P01.sqlite")
    [check] = record.screenings
    assert check["outcome"] == "failed" and check["result"]["failed_types"] == ["protan"]
    assert record.info.finished_at is not None and record.ratings == []
    assert any(e["kind"] == "ended_by_vision_check" for e in record.events)
    assert not any(e["kind"] == "questionnaire" for e in record.events)  # nothing more asked
