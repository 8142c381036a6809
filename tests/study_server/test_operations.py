"""The experimenter's commands: invite, serve's refusals, versions, withdraw, pull's output."""

from __future__ import annotations

import csv
import json
import os
import stat

import pytest

from session_store import read_session
from session_store.invite import read_invite
from stimuli_manifests import fill_checksums, load_manifest, save_manifest
from study_app.remote import ServerClient, ServerRefused, sync_session
from study_app.remote.download import study_plan

from .conftest import ADMIN, db_dump, raw_request, run_cli, write_session


def test_invite_writes_private_tokens_and_stores_only_hashes(served_study, tmp_path):
    out = tmp_path / "invites.csv"
    proc = run_cli("invite", str(served_study), "--n", "3", "--out", str(out), "--server",
                   "https://study.example.org", "--files", str(tmp_path / "links"))
    assert proc.returncode == 0, proc.stderr
    assert stat.S_IMODE(os.stat(out).st_mode) == 0o600
    rows = list(csv.DictReader(out.read_text(encoding="utf-8").splitlines()))
    assert [r["participant"] for r in rows] == ["P01", "P02", "P03"]
    assert len({r["token"] for r in rows}) == 3 and all(len(r["token"]) >= 32 for r in rows)
    assert rows[0]["command"] == (f"cgvq-study run --server https://study.example.org "
                                  f"--participant P01 --token {rows[0]['token']}")
    link = read_invite(tmp_path / "links" / "P02.cgvq-invite.json")
    assert (link.participant, link.token) == ("P02", rows[1]["token"])
    dump = repr(db_dump(served_study))
    assert all(r["token"] not in dump for r in rows)  # only hashes on the server
    again = run_cli("invite", str(served_study), "--n", "2", "--out", str(tmp_path / "b.csv"))
    assert again.returncode == 0
    more = list(csv.DictReader((tmp_path / "b.csv").read_text(encoding="utf-8").splitlines()))
    assert [r["participant"] for r in more] == ["P04", "P05"]
    for args, message in [
        (["--n", "1", "--out", str(out)], "exists already"),
        (["--n", "0", "--out", str(tmp_path / "c.csv")], "at least one"),
        (["--n", "1", "--out", str(tmp_path / "d.csv"), "--prefix", "../x"],
         "participant id"),
        (["--n", "1", "--out", str(tmp_path / "e.csv"), "--server", "ftp://x"], "http"),
    ]:
        proc = run_cli("invite", str(served_study), *args)
        assert proc.returncode == 2 and message in proc.stderr
        assert proc.stderr.count("\n") == 1


def test_serve_refuses_plain_http_on_a_public_address(served_study):
    proc = run_cli("serve", str(served_study), "--host", "0.0.0.0", "--port", "0")
    assert proc.returncode == 2 and "without TLS" in proc.stderr
    assert proc.stderr.count("\n") == 1
    proc = run_cli("serve", str(served_study), "--certfile", "/nonexistent.pem", "--keyfile",
                   "/nonexistent.key")
    assert proc.returncode == 2 and "TLS file not found" in proc.stderr


def test_serve_refuses_a_body_limit_below_the_apps_batches(served_study):
    from session_store.protocol import CLIENT_BATCH_BYTES

    proc = run_cli("serve", str(served_study), "--port", "0", "--max-body",
                   str(CLIENT_BATCH_BYTES))
    _one_line_refusal(proc, "would refuse the app's upload batches (up to 512 KiB")


def _change_manifest(study):
    m = json.loads((study / "manifest.json").read_text())
    m["conditions"] = m["conditions"][:-1]  # one condition dropped
    (study / "manifest.json").write_text(json.dumps(m), encoding="utf-8")
    save_manifest(fill_checksums(load_manifest(study / "manifest.json")),
                  study / "manifest.json")


# about 10 s: CI runs it after `make test` (.ci/run), as `make test-slow` does
@pytest.mark.slow
def test_sessions_stay_on_their_version(served_study, tmp_path, invites, server_factory):
    inv = invites(2)
    srv = server_factory(served_study)
    old_sha = load_manifest(served_study / "manifest.json").sha256
    p1 = tmp_path / "P01.sqlite"
    store = write_session(served_study, p1, "P01", ratings=3)
    sync_session(p1, ServerClient(srv.url, inv[0].token), "P01")
    srv.stop()
    _change_manifest(served_study)
    proc = run_cli("serve", str(served_study), "--port", "0")
    assert proc.returncode == 2 and "--new-version" in proc.stderr
    srv2 = server_factory(served_study, "--new-version")
    new_sha = load_manifest(served_study / "manifest.json").sha256
    c1, c2 = ServerClient(srv2.url, inv[0].token), ServerClient(srv2.url, inv[1].token)
    plan1 = study_plan(c1, "P01", tmp_path / "cache1")
    plan2 = study_plan(c2, "P02", tmp_path / "cache2")
    assert (plan1.manifest_sha256, plan2.manifest_sha256) == (old_sha, new_sha)
    from study_app.remote.download import download_study

    folder = download_study(c1, "P01", plan1)
    assert load_manifest(folder / "manifest.json").sha256 == old_sha
    # P01 finishes on the old version
    from session_store import TrialResult, utc_now

    while (nxt := store.next_trial()) is not None:
        store.record(nxt.index, TrialResult(50.0, 4000.0, 1, 1000.0, 3000.0, utc_now()))
    store.finish()
    store.close()
    assert sync_session(p1, c1, "P01").complete
    with pytest.raises(ServerRefused):
        c1.json("GET", "/api/v1/admin/sessions")
    proc = run_cli("pull", srv2.url, "--admin-token", ADMIN, "--out", str(tmp_path / "p"))
    assert proc.returncode == 0, proc.stderr
    assert f"P01: 12 of 12 ratings, complete, version 1 ({old_sha[:12]})" in proc.stdout
    assert "not started: P02" in proc.stdout
    status, _, page = raw_request(srv2.url, "GET", "/dashboard",
                                  headers={"Authorization": f"Bearer {ADMIN}"})
    assert status == 200 and b"v1" in page and new_sha[:16].encode() in page


@pytest.mark.slow  # about 7 s here: CI runs it after `make test` (.ci/run)
def test_withdraw_while_serving(served_study, tmp_path, invites, server_factory):
    inv = invites(2)
    srv = server_factory(served_study)
    paths = []
    for i in inv:
        path = tmp_path / f"{i.participant}.sqlite"
        write_session(served_study, path, i.participant, ratings=4).close()
        sync_session(path, ServerClient(srv.url, i.token), i.participant)
        paths.append(path)
    (served_study / "sessions").mkdir()
    (served_study / "sessions" / "P01.sqlite").write_bytes(paths[0].read_bytes())
    proc = run_cli("withdraw", str(served_study), "P01", "--reason", "asked to")
    assert proc.returncode == 0, proc.stderr
    assert "P01: 8 uploaded entries deleted" in proc.stdout
    assert not (served_study / "sessions" / "P01.sqlite").exists()
    with pytest.raises(ServerRefused) as exc:
        sync_session(paths[0], ServerClient(srv.url, inv[0].token), "P01")
    assert exc.value.status == 410
    # to anybody else (P02's token, a made-up one) P01 answers as a wrong token does for
    # P02: who withdrew is not told to strangers
    answers = []
    for token, pid in ((inv[1].token, "P01"), ("x" * 43, "P01"), ("x" * 43, "P02")):
        with pytest.raises(ServerRefused) as exc:
            ServerClient(srv.url, token).json("GET", f"/api/v1/participants/{pid}/study")
        answers.append((exc.value.status, str(exc.value).replace(pid, "P")))
    assert answers == [answers[0]] * 3 and answers[0][0] == 403, answers
    dump = db_dump(served_study)
    assert dump["tombstones"][0][:1] == ("P01",)
    assert not any("P01" in repr(r) for t in ("participants", "sessions", "flags")
                   for r in dump[t])
    assert len(dump["entries"]) == 8  # P02's only
    (tmp_path / "p").mkdir()  # an earlier pull left P01's copy there
    (tmp_path / "p" / "P01.sqlite").write_bytes(paths[0].read_bytes())
    (tmp_path / "p" / "P01.sqlite-wal").write_bytes(b"wal")  # SQLite's side file too
    proc = run_cli("pull", srv.url, "--admin-token", ADMIN, "--out", str(tmp_path / "p"),
                   "--csv", str(tmp_path / "r.csv"))
    assert "withdrawn (data deleted): P01" in proc.stdout
    assert f"deleted {tmp_path / 'p' / 'P01.sqlite'}" in proc.stdout
    assert "again" not in proc.stdout  # no earlier pull wrote a table here
    assert not (tmp_path / "p" / "P01.sqlite-wal").exists()
    assert sorted(p.name for p in (tmp_path / "p").glob("*.sqlite")) == ["P02.sqlite"]
    assert len(read_session(tmp_path / "p" / "P02.sqlite").ratings) == 4
    proc = run_cli("withdraw", str(served_study), "P01")
    assert proc.returncode == 2 and "withdrawn already" in proc.stderr


@pytest.mark.slow  # about 8 s here: CI runs it after `make test` (.ci/run)
def test_a_pull_after_a_withdrawal_writes_earlier_tables_again(served_study, tmp_path,
                                                              invites, server_factory):
    """Tables an earlier pull wrote kept a withdrawn participant's rows (the pull only said
    so); a later pull into the same folder writes them again without them, even when it is
    not asked for tables itself, and leaves tables that hold none of them alone."""
    from session_store.answers import write_answers_csv
    from stimuli_manifests.tables import ANSWERS, RATINGS, read_table

    inv = invites(2)
    srv = server_factory(served_study)
    for i in inv:
        path = tmp_path / f"{i.participant}.sqlite"
        write_session(served_study, path, i.participant, ratings=4).close()
        sync_session(path, ServerClient(srv.url, i.token), i.participant)
    out, ratings, answers = tmp_path / "p", tmp_path / "r.csv", tmp_path / "a.csv"
    proc = run_cli("pull", srv.url, "--admin-token", ADMIN, "--out", str(out),
                   "--csv", str(ratings), "--answers", str(answers))
    assert proc.returncode == 0, proc.stderr
    assert {r["participant"] for r in read_table(ratings, RATINGS)} == {"P01", "P02"}
    row = {"study": "s", "session": "x", "participant": "P01", "questionnaire": "q",
           "question": "age", "value": "30", "page": 0, "ms": 1, "answered_at": "t"}
    write_answers_csv([row], answers)  # as if P01 had answered a question
    other = tmp_path / "other.csv"
    other.write_bytes(ratings.read_bytes())  # a copy pull never wrote: not touched
    proc = run_cli("pull", srv.url, "--admin-token", ADMIN, "--out", str(out),
                   "--csv", str(tmp_path / "r2.csv"))  # a later table elsewhere
    assert proc.returncode == 0 and "again" not in proc.stdout
    assert run_cli("withdraw", str(served_study), "P01").returncode == 0
    proc = run_cli("pull", srv.url, "--admin-token", ADMIN, "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    assert f"wrote {ratings.resolve()} again" in proc.stdout
    assert f"wrote {answers.resolve()} again" in proc.stdout
    kept = read_table(ratings, RATINGS)
    assert {r["participant"] for r in kept} == {"P02"} and len(kept) == 4
    assert read_table(answers, ANSWERS) == []
    assert {r["participant"] for r in read_table(tmp_path / "r2.csv", RATINGS)} == {"P02"}
    assert other.read_bytes() != ratings.read_bytes()
    assert stat.S_IMODE(ratings.stat().st_mode) == 0o600
    proc = run_cli("pull", srv.url, "--admin-token", ADMIN, "--out", str(out))
    assert "again" not in proc.stdout  # nothing of P01 left to take out


def test_a_participant_who_withdrew_in_the_app_is_in_no_pulled_table(
        served_study, tmp_path, invites, server_factory):
    """Their ratings went into pull's ratings CSV, which carries no withdrawal, so an analysis
    of the CSV used them (the session files, which carry it, are refused as documented)."""
    from stimuli_manifests.tables import RATINGS, read_table

    inv = invites(2)
    srv = server_factory(served_study)
    for i in inv:
        path = tmp_path / f"{i.participant}.sqlite"
        store = write_session(served_study, path, i.participant, ratings=4)
        if i.participant == "P01":
            store.withdraw("changed my mind")
        store.close()
        sync_session(path, ServerClient(srv.url, i.token), i.participant)
    ratings = tmp_path / "r.csv"
    proc = run_cli("pull", srv.url, "--admin-token", ADMIN, "--out", str(tmp_path / "p"),
                   "--csv", str(ratings), "--answers", str(tmp_path / "a.csv"))
    assert proc.returncode == 0, proc.stderr
    assert "withdrew in the app: P01" in proc.stdout
    assert "their data stay on the server until you delete them with 'cgvq-study withdraw" \
        in proc.stdout
    assert {r["participant"] for r in read_table(ratings, RATINGS)} == {"P02"}
    assert (tmp_path / "p" / "P01.sqlite").is_file()  # the file carries the withdrawal
    # a table an older pull wrote with P01's rows is written again without them
    from session_store import read_session
    from session_store.ratings_csv import write_ratings_csv

    write_ratings_csv(read_session(tmp_path / "p" / "P01.sqlite").ratings, ratings)
    assert {r["participant"] for r in read_table(ratings, RATINGS)} == {"P01"}
    proc = run_cli("pull", srv.url, "--admin-token", ADMIN, "--out", str(tmp_path / "p"))
    assert f"wrote {ratings.resolve()} again" in proc.stdout
    assert {r["participant"] for r in read_table(ratings, RATINGS)} == {"P02"}


def test_pull_with_a_wrong_token_is_one_line(served_study, server_factory, tmp_path):
    srv = server_factory(served_study)
    proc = run_cli("pull", srv.url, "--admin-token", "wrong-token-000000", "--out",
                   str(tmp_path / "p"))
    assert proc.returncode == 2 and "403" in proc.stderr and proc.stderr.count("\n") == 1
    proc = run_cli("pull", "http://127.0.0.1:9", "--admin-token", ADMIN, "--out",
                   str(tmp_path / "p"))
    assert proc.returncode == 2 and "cannot reach" in proc.stderr


@pytest.mark.slow  # about 10 s here: CI runs it after `make test` (.ci/run)
def test_addresses_are_kept_only_when_wanted(served_study, tmp_path, invites, server_factory):
    inv = invites(2)
    # none by default: an address is personal data nothing here shows or uses
    for k, (args, expected) in enumerate(((("--keep-addresses",), "127.0.0.1"), ((), None))):
        srv = server_factory(served_study, *args)
        i = inv[k]
        path = tmp_path / f"{i.participant}.sqlite"
        write_session(served_study, path, i.participant, ratings=1).close()
        sync_session(path, ServerClient(srv.url, i.token), i.participant)
        srv.stop()
        rows = {r[0]: r for r in db_dump(served_study)["participants"]}
        assert rows[i.participant][5] == expected  # last_address


def test_tls_serving_and_a_lab_ca(served_study, tmp_path, invites, server_factory,
                                  monkeypatch):
    import shutil
    import subprocess

    if shutil.which("openssl") is None:
        pytest.skip("openssl is not installed")
    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "2",
                    "-subj", "/CN=127.0.0.1", "-addext", "subjectAltName=IP:127.0.0.1",
                    "-keyout", str(key), "-out", str(cert)], check=True, capture_output=True,
                   timeout=120)
    [inv] = invites(1)
    srv = server_factory(served_study, "--certfile", str(cert), "--keyfile", str(key))
    assert srv.url.startswith("https://")
    path = tmp_path / "P01.sqlite"
    write_session(served_study, path, "P01", ratings=2).close()
    from study_app.remote import ServerUnavailable

    with pytest.raises(ServerUnavailable, match="CERTIFICATE_VERIFY_FAILED"):
        sync_session(path, ServerClient(srv.url, inv.token), "P01")  # unknown CA: refused
    monkeypatch.setenv("CGVQ_CA_FILE", str(cert))
    assert sync_session(path, ServerClient(srv.url, inv.token), "P01").complete


def test_tokens_never_start_with_a_dash(monkeypatch):
    """A token is typed after --token: a leading '-' would read as an option (it failed a CI
    run once, one token in 64 does), so such a draw is drawn again."""
    from study_server import auth

    draws = iter(["-starts-with-a-dash", "-again", "fine_token_0123456789"])
    monkeypatch.setattr(auth.secrets, "token_urlsafe", lambda n: next(draws))
    assert auth.new_token() == "fine_token_0123456789"
    monkeypatch.undo()
    assert not any(auth.new_token().startswith("-") for _ in range(2000))


def _one_line_refusal(proc, says):
    assert proc.returncode == 2, (proc.stdout, proc.stderr)
    assert proc.stderr.count("\n") == 1 and says in proc.stderr, proc.stderr
    assert proc.stdout == ""  # nothing announced (no URL, no admin token)


@pytest.mark.parametrize("folder", ["missing", "empty"])
def test_serve_without_a_study_creates_nothing(tmp_path, folder):
    target = tmp_path / "target"
    if folder == "empty":
        target.mkdir()
    proc = run_cli("serve", str(target), "--port", "0", timeout=60)
    _one_line_refusal(proc, "study folder not found" if folder == "missing" else
                      "holds no manifest.json")
    assert not (target / "server").exists()
    assert (folder == "empty") == target.exists()
    proc = run_cli("backup", str(target), timeout=60)
    assert proc.returncode == 2 and "nothing to back up" in proc.stderr


@pytest.mark.parametrize("args, says", [
    (["--rate", "nan"], "--rate must be a positive number"),
    (["--stats-every", "inf"], "--stats-every must be a positive number"),
    (["--target-raters", "0"], "--target-raters must be at least 1"),
    (["--behind-proxy", "not-an-ip,,"], "no empty entries"),
    (["--behind-proxy", "not-an-ip"], "is not an IP address"),
    (["--host", "no such host!", "--insecure"], "cannot be resolved"),
    # it would change nothing: plain HTTP on this machine is allowed anyway
    (["--host", "127.0.0.1", "--insecure"], "--insecure allows plain HTTP on a host other"),
])
def test_serve_refuses_bad_options_before_anything(served_study, args, says):
    proc = run_cli("serve", str(served_study), "--port", "0", *args, timeout=60)
    _one_line_refusal(proc, says)
    assert not (served_study / "server").exists()


def test_serve_checks_the_tls_files_before_announcing(served_study, tmp_path):
    import shutil
    import subprocess

    text = tmp_path / "text.txt"
    text.write_text("not a certificate\n")
    proc = run_cli("serve", str(served_study), "--port", "0", "--certfile", str(text),
                   "--keyfile", str(text), timeout=60)
    _one_line_refusal(proc, "--certfile")
    assert "is not a PEM certificate" in proc.stderr
    if shutil.which("openssl") is None:
        return
    pairs = []
    for k in (1, 2):
        cert, key = tmp_path / f"cert{k}.pem", tmp_path / f"key{k}.pem"
        subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days",
                        "2", "-subj", "/CN=127.0.0.1", "-keyout", str(key), "-out", str(cert)],
                       check=True, capture_output=True, timeout=120)
        pairs.append((cert, key))
    for keyfile, says in ((text, "is not a PEM private key"),
                          (pairs[1][1], "is not the private key of the certificate")):
        proc = run_cli("serve", str(served_study), "--port", "0", "--certfile",
                       str(pairs[0][0]), "--keyfile", str(keyfile), timeout=60)
        _one_line_refusal(proc, says)
        assert "--keyfile" in proc.stderr
    assert not (served_study / "server").exists()


def test_invite_checks_every_input_before_writing_or_registering(served_study, tmp_path):
    a_file = tmp_path / "text.txt"
    a_file.write_text("x")
    out = tmp_path / "inv.csv"
    proc = run_cli("invite", str(served_study), "--n", "2", "--out", str(out), "--files",
                   str(a_file))
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1
    assert "--files" in proc.stderr and "is a file" in proc.stderr
    assert not out.exists() and not (served_study / "server").exists()

    proc = run_cli("invite", str(served_study), "--n", "100000000", "--out", str(out),
                   timeout=60)
    assert proc.returncode == 2 and "from 1 to 10000" in proc.stderr and not out.exists()

    folder = tmp_path / "a-folder"
    folder.mkdir()
    proc = run_cli("invite", str(served_study), "--n", "1", "--out", str(folder))
    assert proc.returncode == 2 and "is a folder" in proc.stderr
    assert "earlier tokens" not in proc.stderr

    # invite files that exist already: refused after reading the ids, nobody registered
    assert run_cli("invite", str(served_study), "--n", "1", "--out",
                   str(tmp_path / "first.csv")).returncode == 0
    links = tmp_path / "links"
    links.mkdir()
    (links / "P02.cgvq-invite.json").write_text("{}")
    proc = run_cli("invite", str(served_study), "--n", "1", "--out", str(out), "--files",
                   str(links))
    assert proc.returncode == 2 and "holds invite files already" in proc.stderr
    assert not out.exists()
    assert [r[0] for r in db_dump(served_study)["participants"]] == ["P01"]


def test_a_host_that_cannot_be_a_name_is_refused_without_asking_a_name_server(monkeypatch):
    from session_store.errors import StudyError
    from study_server import serve

    def lookup(*_args, **_kw):
        pytest.fail("a name server was asked")

    monkeypatch.setattr(serve.socket, "getaddrinfo", lookup)
    for host in ("no such host!", "a b", "", "[::1]"):
        with pytest.raises(StudyError, match="neither an IP address nor a host name"):
            serve.resolve_host(host, 0)
    for address in ("127.0.0.1", "0.0.0.0", "::1"):
        serve.resolve_host(address, 0)  # addresses need no lookup


def test_a_generated_admin_token_is_not_printed_into_a_pipe(served_study):
    """Run as a service, serve's first start printed the generated admin token into the
    journal, where whoever reads the logs could take the dashboard and every session."""
    from study_server.child import ServeProcess

    from .conftest import REPO, cli_env

    env = {k: v for k, v in cli_env().items() if k != "CGVQ_ADMIN_TOKEN"}
    srv = ServeProcess(served_study, env=env, cwd=REPO).start()
    srv.stop()
    token = (served_study / "server" / "admin_token").read_text().strip()
    said = "".join(srv.output)
    assert len(token) >= 32 and token not in said
    assert "admin token: generated and kept in" in said and "not printed" in said
