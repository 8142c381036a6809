"""The participant's start, outside the trials: a skipped display check stays on record
after a resume without the option, fast gaming monitors are measured (see test_vsync), a
returning participant whose display fails is told their answers are kept, an unreadable note
of the last download does not crash an offline start, messages name options that exist, an
id typed in another case is refused alike on every OS, and the frozen app opens an
invitation file it is given."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path
from types import SimpleNamespace

import pytest
from support.sessions import session_entries

from cgvq_cli.study_cli import build_parser
from cgvq_cli.study_cli import main as study
from session_store import SessionStore, read_session
from session_store.errors import StudyError
from session_store.schedule import make_schedule, participant_seed, schedule_items
from session_store.study_folder import load_study
from study_app.app import App, RunOptions
from study_app.preflight import Check
from study_app.remote.download import check_disk_space
from study_app.screens import content
from study_server.stats import participant_stats

REPO = Path(__file__).resolve().parents[2]


def _names(keys, action):
    return keys.label(action)


def _session(study_dir: Path, pid: str = "P07") -> Path:
    study = load_study(study_dir)
    m = study.manifest
    path = study.session_path(pid)
    SessionStore.create(path, participant=pid, study_id=m.study_id,
                        manifest_sha256=study.loaded.sha256,
                        seed=participant_seed(m.study_id, pid), app_version="t",
                        plan=make_schedule(schedule_items(m), 1, 1)).close()
    return path


def test_a_skipped_check_stays_on_record_after_a_resume_without_it(tiny_study):
    path = _session(tiny_study)
    failed = [{"name": "refresh_rate", "ok": False, "message": "30 Hz"}]
    with SessionStore.open(path) as store:
        store.save_preflight(failed, skipped=True)  # run 1: --skip-preflight
    with SessionStore.open(path) as store:  # run 2: resumed without it, the check passes
        store.save_preflight([{"name": "refresh_rate", "ok": True, "message": "60 Hz"}],
                             skipped=False)
    record = read_session(path)
    assert record.info.preflight_skipped is True
    # The dashboard reads the same from the entries the server receives.
    rows = [("P07", "sha", e.kind, json.dumps(e.body), "s1") for e in session_entries(path)]
    ps = participant_stats(rows)["P07"]
    assert ps.preflight_skipped is True and ps.preflight_failed == ["refresh_rate"]


def test_a_returning_participant_whose_display_fails_is_told_the_answers_are_kept():
    failed = [Check("screen_size", False, "the window is 1024x768, the study needs 1280x1024")]
    new = content.preflight_failed(failed, _names)
    assert "Nothing was recorded" in new.body
    back = content.preflight_failed(failed, _names, (3, 9))
    assert "Nothing was recorded" not in back.body
    assert "Your 3 of 9 answers so far are saved" in back.body
    assert "start the study again the same way" in back.body


def test_an_unreadable_note_of_the_last_download_gives_one_line(tmp_path, capsys):
    invite = tmp_path / "P07.cgvq-invite.json"
    invite.write_text(json.dumps({"format": "cgvq-invite/1", "server": "http://127.0.0.1:9",
                                  "participant": "P07", "token": "x" * 32}))
    for note in ("", '{"server": "http://127.0.0.1:9"}', "[1, 2]"):
        (tmp_path / "last-P07.json").write_text(note)
        code = study(["run", "--invite", str(invite), "--data-dir", str(tmp_path)])
        err = capsys.readouterr().err.strip().splitlines()
        assert code == 2 and len(err) == 1 and "cannot reach" in err[0], err


def test_the_disk_space_message_names_an_option_run_has(tmp_path):
    plan = SimpleNamespace(missing_bytes=lambda: 10**18, folder=tmp_path / "study")
    with pytest.raises(StudyError) as caught:
        check_disk_space(plan)  # type: ignore[arg-type]
    parser, _ = build_parser()
    run_parser = parser._subparsers._group_actions[0].choices["run"]
    options = {o for a in run_parser._actions for o in a.option_strings}
    named = {w.strip("().,") for w in str(caught.value).split() if w.startswith("--")}
    assert named and named <= options, named - options


def test_an_id_in_another_case_is_refused_on_every_file_system(tiny_study):
    _session(tiny_study, "P07")
    study = load_study(tiny_study)
    assert App(study, RunOptions(participant="P07"))._check_existing() is True
    with pytest.raises(StudyError, match="give --participant P07 to continue it"):
        App(study, RunOptions(participant="p07"))._check_existing()
    assert not (tiny_study / "sessions" / "p07.sqlite").exists()


def _frozen_entry():
    spec = importlib.util.spec_from_file_location(
        "participant_app", REPO / "packaging" / "participant_app.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_frozen_app_opens_an_invitation_file_it_is_given(tmp_path, capsys):
    entry = _frozen_entry()
    file = str(tmp_path / "P07.cgvq-invite.json")
    assert entry.command_line([file]) == ["run", "--invite", file]
    assert entry.command_line(["run", "--help"]) == ["run", "--help"]
    assert entry.run([]) == 0  # a double-click on the app: says what to do
    assert "open your invitation file" in capsys.readouterr().out


def test_the_frozen_app_opened_with_a_file_waits_before_its_window_closes(tmp_path, capsys,
                                                                          monkeypatch):
    """Dragged onto the app, the invitation runs in a console the system closes with the
    app: an error (here, the file is missing) vanished before anyone could read it."""
    entry = _frozen_entry()

    class Console:
        def isatty(self) -> bool:
            return True

    prompts: list[str] = []
    monkeypatch.setattr(entry.sys, "stdin", Console())
    monkeypatch.setattr("builtins.input", lambda text="": prompts.append(text) or "")
    file = str(tmp_path / "P07.cgvq-invite.json")  # not there
    assert entry.run([file]) == 2
    assert prompts == ["Press Enter to close this window."]
    assert "P07.cgvq-invite.json" in capsys.readouterr().err
    prompts.clear()
    assert entry.run(["verify", str(tmp_path / "none.sqlite")]) == 2  # typed: no wait
    assert prompts == []
