"""The cgvq-manifest/1 model: round trip, defaults, ids, and every validation error path."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from stimuli_manifests import (
    DEFAULT_LABELS,
    ManifestError,
    fill_checksums,
    load_manifest,
    parse_manifest,
    save_manifest,
    sha256_file,
    validate_manifest,
)


def minimal(**overrides) -> dict:
    doc = {
        "format": "cgvq-manifest/1",
        "study_id": "s1",
        "root": "videos",
        "references": [{"path": "a/ref.mkv", "scene": "A"}, {"path": "b/ref.mkv", "scene": "B"}],
        "conditions": [
            {"reference": "SRC01", "path": "a/n1.mkv", "method": "noise", "level": 1},
            {"reference": "SRC01", "path": "a/n2.mkv", "method": "noise", "level": 2},
            {"reference": "SRC02", "path": "b/n1.mkv", "method": "noise", "level": 1},
            {"reference": "SRC02", "path": "b/blur1.mkv", "method": "blur", "level": 1},
        ],
    }
    doc.update(overrides)
    return doc


def write_study(tmp_path: Path, doc: dict, files: bool = True) -> Path:
    path = tmp_path / "manifest.json"
    path.write_text(json.dumps(doc))
    if files:
        for item in doc["references"] + doc["conditions"]:
            f = tmp_path / doc.get("root", ".") / item["path"]
            f.parent.mkdir(parents=True, exist_ok=True)
            f.write_bytes(item["path"].encode())  # distinct content per file
    return path


def test_defaults_are_the_five_impairment_labels():
    m = parse_manifest(minimal())
    assert [(lab.position, lab.text) for lab in m.scale.labels] == list(DEFAULT_LABELS)
    assert [lab.text for lab in m.scale.labels] == [
        "Very annoying",
        "Annoying",
        "Slightly annoying",
        "Perceptible but not annoying",
        "Imperceptible",
    ]
    assert [lab.position for lab in m.scale.labels] == [0, 25, 50, 75, 100]
    assert (m.scale.min, m.scale.max) == (0, 100)
    assert m.protocol.repetitions == 3 and m.protocol.blank_seconds == 0.5
    assert m.protocol.hidden_reference is True


def test_vqeg_ids_number_hrcs_by_method_and_level_across_sources():
    m = parse_manifest(minimal())
    assert [r.id for r in m.references] == ["SRC01", "SRC02"]
    # (noise,1) -> HRC01, (noise,2) -> HRC02, (blur,1) -> HRC03, the same for every source
    assert [c.id for c in m.conditions] == [
        "SRC01_HRC01",
        "SRC01_HRC02",
        "SRC02_HRC01",
        "SRC02_HRC03",
    ]


def test_user_ids_are_kept():
    doc = minimal()
    doc["references"][0]["id"] = "bistro"
    doc["conditions"][0]["reference"] = "bistro"
    doc["conditions"][1]["reference"] = "bistro"
    doc["conditions"][1]["id"] = "bistro-noisy"
    m = parse_manifest(doc)
    assert m.references[0].id == "bistro"
    assert m.conditions[1].id == "bistro-noisy"
    assert m.conditions[0].id == "bistro_HRC01"


def test_stimuli_include_hidden_references_only_when_enabled():
    m = parse_manifest(minimal())
    stims = m.stimuli()
    hidden = [s for s in stims if s.is_hidden_reference]
    assert [s.id for s in hidden] == ["SRC01", "SRC02"]
    assert all(s.reference == s.id and s.method == "reference" and s.level is None for s in hidden)
    assert {s.scene for s in stims} == {"A", "B"}
    m2 = parse_manifest(minimal(protocol={"hidden_reference": False}))
    assert len(m2.stimuli()) == 4


def test_round_trip_through_a_file(tmp_path):
    doc = minimal(title="T", protocol={"repetitions": 2, "blank_seconds": 0.25})
    doc["conditions"][0]["metadata"] = {"spp": 4, "nested": {"x": [1, 2]}}
    m = parse_manifest(doc)
    path = save_manifest(m, tmp_path / "sub" / "m.json")
    loaded = load_manifest(path)
    assert loaded.manifest == m
    assert loaded.root == tmp_path / "sub" / "videos"
    assert loaded.sha256 == sha256_file(path)
    # saving the loaded manifest again gives the same bytes
    path2 = save_manifest(loaded.manifest, tmp_path / "m2.json")
    assert path2.read_bytes() == path.read_bytes()
    assert json.loads(path.read_text())["conditions"][0]["metadata"]["nested"] == {"x": [1, 2]}


@pytest.mark.parametrize(
    ("mutate", "needle"),
    [
        (lambda d: d.pop("study_id"), "study_id"),
        (lambda d: d.update(format="cgvq-manifest/2"), "major version 2"),
        (lambda d: d.update(format="other/1"), "format"),
        (lambda d: d.update(references=[]), "references"),
        (lambda d: d["conditions"][0].update(reference="SRC09"), "SRC09"),
        (lambda d: d["conditions"][0].update(level=-1), "conditions.0.level"),
        (lambda d: d["conditions"][0].update(method=""), "conditions.0.method"),
        (lambda d: d["conditions"][0].update(sha256="abc"), "sha256"),
        (lambda d: d["conditions"][0].update(id="bad id!"), "bad id!"),
        (lambda d: d["conditions"][0].update(levle=2), "levle"),
        (lambda d: [c.update(id="X") for c in d["conditions"][:2]], "duplicate"),
        (lambda d: [r.update(id="R") for r in d["references"]], "duplicate reference id(s): R"),
        (lambda d: d.update(scale={"min": 0, "max": 0}), "scale"),
        (lambda d: d.update(scale={"labels": [{"position": 120, "text": "x"}]}), "outside"),
        (
            lambda d: d.update(
                scale={"labels": [{"position": 50, "text": "a"}, {"position": 10, "text": "b"}]}
            ),
            "increasing",
        ),
        (lambda d: d.update(protocol={"repetitions": 0}), "protocol.repetitions"),
        (lambda d: d.update(protocol={"allocation": "clever"}), "'full' or 'adaptive'"),
        (lambda d: d.update(protocol={"adaptive": {"blocks": 3}}), "allocation to 'adaptive'"),
        (lambda d: d.update(protocol={"allocation": "adaptive", "adaptive": {"blocks": 1}}),
         "protocol.adaptive.blocks"),
        (lambda d: d.update(protocol={"allocation": "adaptive",
                                      "adaptive": {"block_trials": 10_000}}),
         "cannot be filled"),
        (lambda d: d.update(protocol={"allocation": "adaptive", "hidden_reference": False}),
         "needs protocol.hidden_reference: true"),
        (lambda d: d["references"][0].update(path="../outside.mkv"), "'..'"),
        (lambda d: d["references"][0].update(path="/etc/passwd"), "absolute"),
        (lambda d: d["conditions"][2].update(path="b\\n1.mkv"), "separators"),
        (lambda d: d["conditions"][2].update(path="C:/x.mkv"), "drive"),
        (lambda d: d["conditions"][3].update(path="  "), "empty"),
    ],
)
def test_validation_errors_name_the_field(mutate, needle):
    doc = minimal()
    mutate(doc)
    with pytest.raises(ManifestError) as err:
        parse_manifest(doc)
    assert needle in str(err.value)


def test_unreadable_documents(tmp_path):
    with pytest.raises(ManifestError, match="not found"):
        load_manifest(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ManifestError, match="not valid JSON"):
        load_manifest(bad)
    bad.write_text("[1, 2]")
    with pytest.raises(ManifestError, match="JSON object"):
        load_manifest(bad)


def test_structure_only_needs_no_files(tmp_path):
    path = write_study(tmp_path, minimal(), files=False)
    loaded = load_manifest(path)
    assert validate_manifest(loaded, structure_only=True).ok
    report = validate_manifest(loaded)
    assert not report.ok and "does not exist" in report.errors[0]


def test_missing_file_is_reported(tmp_path):
    path = write_study(tmp_path, minimal())
    (tmp_path / "videos" / "a" / "n2.mkv").unlink()
    report = validate_manifest(load_manifest(path))
    assert not report.ok
    assert report.errors == [f"SRC01_HRC02: file {tmp_path / 'videos/a/n2.mkv'} does not exist"]
    assert report.checked_files == 5


def test_checksums_verify_and_report_mismatch(tmp_path):
    path = write_study(tmp_path, minimal())
    loaded = load_manifest(path)
    report = validate_manifest(loaded)
    assert report.ok and len(report.warnings) == 6  # no checksums recorded yet
    hashed = fill_checksums(loaded)
    import hashlib

    assert hashed.conditions[0].sha256 == hashlib.sha256(b"a/n1.mkv").hexdigest()
    save_manifest(hashed, path)
    loaded = load_manifest(path)
    assert validate_manifest(loaded).ok
    (tmp_path / "videos" / "b" / "blur1.mkv").write_bytes(b"tampered")
    report = validate_manifest(loaded)
    assert not report.ok
    (mismatch,) = report.mismatches
    assert mismatch.stimulus_id == "SRC02_HRC03"
    assert mismatch.actual == hashlib.sha256(b"tampered").hexdigest()
    assert mismatch.expected == hashlib.sha256(b"b/blur1.mkv").hexdigest()
    with pytest.raises(ManifestError, match="SRC02_HRC03"):
        report.raise_for_errors()


def test_symlink_leaving_the_root_is_refused(tmp_path):
    outside = tmp_path / "secret.mkv"
    outside.write_bytes(b"x")
    path = write_study(tmp_path, minimal())
    link = tmp_path / "videos" / "a" / "n1.mkv"
    link.unlink()
    os.symlink(outside, link)
    loaded = load_manifest(path)
    report = validate_manifest(loaded)
    assert not report.ok
    assert any("outside the root" in e and "SRC01_HRC01" in e for e in report.errors)
    with pytest.raises(ManifestError, match="outside the root"):
        loaded.stimulus_path("SRC01_HRC01")
    # a symlink that stays inside the root is fine
    link.unlink()
    os.symlink(tmp_path / "videos" / "a" / "ref.mkv", link)
    assert load_manifest(path).stimulus_path("SRC01_HRC01") == link


def test_root_override(tmp_path):
    path = write_study(tmp_path, minimal(root="nowhere"), files=False)
    data = tmp_path / "elsewhere"
    for rel in ["a/ref.mkv", "b/ref.mkv", "a/n1.mkv", "a/n2.mkv", "b/n1.mkv", "b/blur1.mkv"]:
        (data / rel).parent.mkdir(parents=True, exist_ok=True)
        (data / rel).write_bytes(b"v")
    assert not validate_manifest(load_manifest(path)).ok
    assert validate_manifest(load_manifest(path, root=data)).ok
