"""``cgvq-study panel``: the templates go into a manifest once, not under collected sessions,
and the listing says what the panel asks."""

from __future__ import annotations

import json

from support.studies import make_study

from cgvq_cli.study_cli import main
from stimuli_manifests import load_manifest
from stimuli_manifests.panel_templates import DEMOGRAPHICS, POST_STUDY_SURVEY


def test_templates_added_once_and_listed(tmp_path, capsys):
    study = make_study(tmp_path / "study")
    before = json.loads((study / "manifest.json").read_text())
    assert main(["panel", str(study)]) == 0
    assert "has no panel block" in capsys.readouterr().out
    assert main(["panel", str(study), "--add-templates", "--acuity", "--on-fail", "end"]) == 0
    out = capsys.readouterr().out
    m = load_manifest(study / "manifest.json").manifest
    assert [q.id for q in m.panel.questionnaires] == [DEMOGRAPHICS["id"], POST_STUDY_SURVEY["id"]]
    vs = m.panel.vision_screening
    assert (vs.colour, vs.acuity, vs.on_fail) == (True, True, "end")
    after = json.loads((study / "manifest.json").read_text())
    assert {k: v for k, v in after.items() if k != "panel"} == before  # nothing else changed
    assert "post_study (after the last trial, voluntary)" in out
    assert "vision checks: colour, acuity at 60 cm; a failed check: end" in out

    assert main(["panel", str(study), "--add-templates"]) == 2
    assert "already has a panel block" in capsys.readouterr().err


def test_templates_are_not_added_under_sessions(tmp_path, capsys):
    study = make_study(tmp_path / "study")
    (study / "sessions").mkdir()
    (study / "sessions" / "P01.sqlite").write_bytes(b"x")
    assert main(["panel", str(study), "--add-templates"]) == 2
    assert "already holds session files" in capsys.readouterr().err
    assert load_manifest(study / "manifest.json").manifest.panel is None


def test_template_options_without_add_templates_are_refused(tmp_path, capsys):
    study = make_study(tmp_path / "study")
    before = (study / "manifest.json").read_bytes()
    for args in (["--acuity"], ["--on-fail", "end"], ["--no-colour-check"],
                 ["--on-fail", "flag"]):
        assert main(["panel", str(study), *args]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "--add-templates" in err and args[0] in err, err
    assert (study / "manifest.json").read_bytes() == before


def test_on_fail_without_any_vision_check_is_refused(tmp_path, capsys):
    study = make_study(tmp_path / "study")
    before = (study / "manifest.json").read_bytes()
    assert main(["panel", str(study), "--add-templates", "--no-colour-check",
                 "--on-fail", "end"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--on-fail needs a vision check to act on" in err, err
    assert (study / "manifest.json").read_bytes() == before


def test_the_acuity_check_runs_where_participants_sit(tmp_path, capsys):
    """A study seated at 75 cm gets its vision checks at 75 cm (the templates said 60); a
    check at another distance than the seating is named by panel and by check."""
    from stimuli_manifests import save_manifest

    study = make_study(tmp_path / "study")
    loaded = load_manifest(study / "manifest.json")
    data = loaded.manifest.model_dump(mode="json", exclude_none=True)
    data["protocol"]["viewing_distance_cm"] = 75
    from stimuli_manifests import parse_manifest

    save_manifest(parse_manifest(data), study / "manifest.json")
    assert main(["panel", str(study), "--add-templates", "--acuity"]) == 0
    out = capsys.readouterr().out
    assert "acuity at 75 cm" in out and "warning" not in out
    assert load_manifest(study / "manifest.json").manifest.panel.vision_screening \
        .viewing_distance_cm == 75
    data = json.loads((study / "manifest.json").read_text())
    data["panel"]["vision_screening"]["viewing_distance_cm"] = 60
    (study / "manifest.json").write_text(json.dumps(data))
    assert main(["panel", str(study)]) == 0
    said = ("the acuity check runs at 60 cm, but participants are told to sit 75 cm from "
            "the screen while they rate")
    assert said in capsys.readouterr().out
    main(["check", str(study)])
    assert said in capsys.readouterr().out
