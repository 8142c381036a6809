"""Briefing and consent texts carry sha256 checksums in the manifest, like the videos."""

from __future__ import annotations

import hashlib

import pytest

from cgvq_cli.study_cli import main
from session_store.study_folder import load_study
from stimuli_manifests import (
    StimuliError,
    fill_checksums,
    load_manifest,
    parse_manifest,
    save_manifest,
    validate_manifest,
)
from study_app.preflight import check_checksums
from study_app.study_check import check_study


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def test_fill_checksums_records_the_texts_beside_the_manifest(tiny_study):
    m = load_manifest(tiny_study / "manifest.json").manifest
    assert m.texts == {
        "briefing.md": _sha((tiny_study / "briefing.md").read_bytes()),
        "consent.md": _sha((tiny_study / "consent.md").read_bytes()),
    }
    study = load_study(tiny_study)
    assert study.text_sha256("consent.md") == m.texts["consent.md"]
    assert check_checksums(study).ok


def test_a_changed_consent_text_fails_check_and_preflight(tiny_study, capsys):
    (tiny_study / "consent.md").write_text("I agree to something else.\n", encoding="utf-8")
    study = load_study(tiny_study)
    result = check_study(study)
    assert any("consent.md" in e for e in result.errors)
    c = check_checksums(study)
    assert not c.ok and "consent.md" in c.message
    assert main(["check", str(tiny_study)]) == 2
    assert "consent.md" in capsys.readouterr().out


def test_missing_recorded_text_and_unrecorded_text(tiny_study):
    (tiny_study / "briefing.md").unlink()
    report = validate_manifest(load_manifest(tiny_study / "manifest.json"))
    assert any("briefing.md: recorded in the manifest but missing" in e for e in report.errors)
    # A text present but not recorded is a warning (older manifests), not an error.
    loaded = load_manifest(tiny_study / "manifest.json")
    m = loaded.manifest.model_copy(deep=True)
    m.texts = {}
    save_manifest(m, tiny_study / "manifest.json")
    report = validate_manifest(load_manifest(tiny_study / "manifest.json"))
    assert report.ok and any("consent.md: no sha256" in w for w in report.warnings)
    # fill_checksums drops the entry of a text that is gone.
    m = fill_checksums(load_manifest(tiny_study / "manifest.json"))
    assert set(m.texts) == {"consent.md"}


def test_texts_only_name_the_study_texts():
    base = {"study_id": "s", "references": [{"path": "a.mkv"}]}
    with pytest.raises(StimuliError, match="not one of"):
        parse_manifest({**base, "texts": {"../evil.md": "0" * 64}})
    with pytest.raises(StimuliError, match="64 hexadecimal"):
        parse_manifest({**base, "texts": {"consent.md": "abc"}})


def test_the_consent_hash_is_of_the_file_bytes(tmp_path, study_factory):
    study_dir = study_factory(tmp_path / "s")
    raw = "Ich stimme zu.\r\nÜbrigens: **fett**\r\n".encode()
    (study_dir / "consent.md").write_bytes(raw)
    save_manifest(fill_checksums(load_manifest(study_dir / "manifest.json")),
                  study_dir / "manifest.json")
    study = load_study(study_dir)
    assert study.text_sha256("consent.md") == _sha(raw)
    assert study.consent == "Ich stimme zu.\nÜbrigens: **fett**\n"

