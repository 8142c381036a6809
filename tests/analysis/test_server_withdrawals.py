"""A participant withdrawn on the server (``cgvq-study withdraw``: their data deleted there)
came back into the numbers through a copy of their session: one kept from an earlier pull,
or the file they had e-mailed. The pull's own listing said they had withdrawn. And the text
for the paper counted neither them nor others whose data had been deleted."""

from __future__ import annotations

import json
import shutil

import pandas as pd
from support.cli import analyze
from support.sessions import blur_manifest, player_session

from session_store.protocol import PULL_LISTING_FILE
from stimuli_manifests import load_manifest

OPTIONS = ("--model", "mos", "--outliers", "none", "--bootstrap", "20", "--splits", "20")


def _study(folder):
    return blur_manifest(folder, "withdrawals")


def _pull(tmp_path):
    """A pull of P1..P4 after P2 and P5 were withdrawn on the server, with P2's copy from
    an earlier pull put back in (P5's file is gone)."""
    manifest = _study(tmp_path)
    loaded = load_manifest(manifest)
    earlier = tmp_path / "earlier"
    earlier.mkdir()
    for k, p in enumerate(("P1", "P2", "P3", "P4")):
        player_session(earlier, loaded, p, seed=k + 1)
    pulled = tmp_path / "pulled"
    shutil.copytree(earlier, pulled)
    withdrawn = [{"participant": "P2", "withdrawn_at": "2026-11-20T10:00:00Z"},
                 {"participant": "P5", "withdrawn_at": "2026-11-21T09:00:00Z"}]
    (pulled / PULL_LISTING_FILE).write_text(json.dumps({
        "study_id": "withdrawals", "withdrawn": withdrawn,
        "participants": [{"participant": p, "session": {"n_ratings": 6}}
                         for p in ("P1", "P2", "P3", "P4")]}))
    return manifest, earlier, pulled


def _summary(out):
    return json.loads((out / "summary.json").read_text())


def test_a_copy_of_a_withdrawn_participant_is_refused_and_both_are_counted(tmp_path, capsys):
    manifest, _, pulled = _pull(tmp_path)
    out = tmp_path / "r"
    code, _, err = analyze(capsys, "report", "--manifest", manifest, "--sessions", pulled,
                           *OPTIONS, "--out", out)
    assert code == 0, err
    s = _summary(out)
    assert s["n_raters_input"] == 3 and sorted(s["withdrawn"]) == ["P2", "P5"]
    exclusions = pd.read_csv(out / "tables" / "exclusions.csv")
    copy = exclusions[exclusions["who"].astype(str).str.endswith("P2.sqlite")]
    assert list(copy["kind"]) == ["refused session"]
    assert ("participant P2 withdrew and their data were deleted on the server on 2026-11-20"
            in copy["reason"].iloc[0]) and "delete it" in copy["reason"].iloc[0]
    gone = exclusions[exclusions["who"] == "P5"]
    assert list(gone["kind"]) == ["withdrawn participant"]
    matrix = pd.read_csv(out / "rating_matrix_p910.csv")
    assert not any(c.startswith("P2") for c in matrix.columns)
    assert "P2" not in (out / "sureal_dataset.json").read_text()
    methods = " ".join((out / "methods.txt").read_text().split())
    assert "5 participants took part and 2 withdrew" in methods


def _counted(rs):
    """Raters in the numbers, and those counted as withdrawn (as summary.json has them)."""
    from analysis.sessions import withdrawn_participants

    return rs.n_raters, sorted(withdrawn_participants(rs.exclusions))


def test_a_file_given_by_itself_beside_the_pull_is_refused_too(tmp_path, caplog):
    from analysis import load_ratings

    manifest, earlier, pulled = _pull(tmp_path)
    (pulled / "P2.sqlite").unlink()  # the pull deleted it; the old copy is named on its own
    rs = load_ratings(manifest, sessions=[pulled, earlier / "P2.sqlite"])
    assert _counted(rs) == (3, ["P2", "P5"])
    assert "data were deleted on the server" in caplog.text


def test_rows_of_a_withdrawn_participant_in_a_ratings_table_beside_the_listing(tmp_path):
    from analysis import load_ratings

    manifest, _, pulled = _pull(tmp_path)
    stimuli = ["R0", "R1"] + [f"R{i}_blur_L{lv}" for i in range(2) for lv in (1, 2)]
    rows = [{"participant": p, "stimulus": stim, "rating": 20 + 10 * k + j}
            for j, p in enumerate(("P1", "P2", "P3", "P4")) for k, stim in enumerate(stimuli)]
    pd.DataFrame(rows).to_csv(pulled / "ratings.csv", index=False)
    rs = load_ratings(manifest, ratings_csv=pulled / "ratings.csv")
    assert _counted(rs) == (3, ["P2", "P5"])
    refused = [x for x in rs.exclusions if x.kind == "refused session"]
    assert len(refused) == 1 and refused[0].who.endswith("ratings.csv (6 rows)")
    # a table of another study beside the listing is not touched by it
    listing = json.loads((pulled / PULL_LISTING_FILE).read_text())
    (pulled / PULL_LISTING_FILE).write_text(json.dumps({**listing, "study_id": "other"}))
    assert _counted(load_ratings(manifest, ratings_csv=pulled / "ratings.csv")) == (4, [])


def test_verify_names_the_copy_of_a_participant_withdrawn_on_the_server(tmp_path, capsys):
    """``verify`` called such a copy "intact and complete" and exited 0."""
    from cgvq_cli.study_cli import main

    _, _, pulled = _pull(tmp_path)
    assert main(["verify", str(pulled)]) == 1
    out = capsys.readouterr().out
    (line,) = [ln for ln in out.splitlines() if "WITHDRAWN ON THE SERVER" in ln]
    assert "participant P2 withdrew and their data were deleted on the server on 2026-11-20" \
        in line and "delete it" in line
    assert out.count("WITHDRAWN ON THE SERVER") == 1  # P1, P3, P4 are not named
