"""The shared pieces every package uses: versioned CSV contracts and the one CLI runner."""

from __future__ import annotations

import csv
import errno

import pytest

from stimuli_manifests import tables
from stimuli_manifests.cli_runner import OneLineParser, run_command
from stimuli_manifests.errors import MissingExtraError, TableError, ToolkitError
from stimuli_manifests.extras import explain_missing


def _row(fmt: tables.TableFormat, **over):
    row = {c: f"v_{c}" for c in fmt.required}
    row.update(over)
    return row


def test_written_table_carries_its_version_and_reads_back(tmp_path):
    path = tables.write_table(tmp_path / "s.csv", tables.SCORES,
                              [_row(tables.SCORES, score="1.5", pooling="mean", zeta=3),
                               _row(tables.SCORES)],
                              columns=("pooling", "zeta"))
    with path.open(newline="") as fh:
        header = next(csv.reader(fh))
    assert header == [*tables.SCORES.required, "pooling", "zeta", "format"]
    rows = tables.read_table(path, tables.SCORES)
    assert rows[0]["score"] == "1.5" and "format" not in rows[0]
    assert rows[0]["zeta"] == "3" and rows[1]["pooling"] == ""
    with path.open(newline="") as fh:
        assert {r["format"] for r in csv.DictReader(fh)} == {"cgvq-scores/1.1"}


def test_unknown_major_version_and_foreign_tables_are_refused(tmp_path):
    path = tables.write_table(tmp_path / "r.csv", tables.RATINGS, [_row(tables.RATINGS)])
    text = path.read_text().replace(tables.RATINGS.version, "cgvq-ratings/2.3")
    path.write_text(text)
    with pytest.raises(TableError, match=r"cgvq-ratings/2\.3 is not supported"):
        tables.read_table(path, tables.RATINGS)
    path.write_text(text.replace("cgvq-ratings/2.3", "cgvq-scores/1"))
    with pytest.raises(TableError, match="not a cgvq-ratings table"):
        tables.read_table(path, tables.RATINGS)
    # a minor version adds optional columns only: still readable
    path.write_text(text.replace("cgvq-ratings/2.3", "cgvq-ratings/1.4"))
    assert len(tables.read_table(path, tables.RATINGS)) == 1


def test_missing_required_columns_are_named(tmp_path):
    path = tmp_path / "d.csv"
    path.write_text("stimulus,dmos\nA,1\n")
    with pytest.raises(TableError, match="reference, method, level"):
        tables.read_table(path, tables.DMOS)


def test_files_without_the_format_column_read_as_version_1(tmp_path):
    path = tmp_path / "legacy.csv"
    cols = tables.DMOS.required
    path.write_text(",".join(cols) + "\n" + ",".join("x" for _ in cols) + "\n")
    assert tables.read_table(path, tables.DMOS)[0]["model"] == "x"


def test_a_row_without_a_written_column_is_a_table_error(tmp_path):
    with pytest.raises(TableError, match="lacks column 'session'"):
        tables.write_table(tmp_path / "r.csv", tables.RATINGS, [{"study": "s"}])
    assert list(tmp_path.iterdir()) == []  # nothing half-written is left


def test_runner_turns_user_errors_into_one_line_and_exit_2(capsys):
    def bad():
        raise ToolkitError("first line\nsecond line")

    assert run_command("prog sub", bad) == 2
    err = capsys.readouterr().err
    assert err == "prog sub: error: first line second line\n"


def test_usage_errors_are_one_line_too_in_subcommands(capsys):
    parser = OneLineParser(prog="tool")
    sub = parser.add_subparsers(dest="cmd", required=True)
    run = sub.add_parser("run")
    run.add_argument("--pool", choices=["max", "mean"])
    run.add_argument("--steps", type=int)
    for argv, why in ((["run", "--pool", "median"], "invalid choice: 'median'"),
                      (["run", "--steps", "x"], "invalid int value: 'x'"),
                      (["fly"], "invalid choice: 'fly'"), ([], "required: cmd")):
        with pytest.raises(SystemExit) as exit_:
            parser.parse_args(argv)
        assert exit_.value.code == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and why in err, err
        assert err.startswith("tool") and err.rstrip().endswith("--help)")
    assert parser.parse_args(["run", "--pool", "max"]).pool == "max"


def test_runner_reports_os_errors_on_user_paths(capsys):
    def too_long():
        raise OSError(errno.ENAMETOOLONG, "File name too long", "x" * 300)

    assert run_command("prog", too_long) == 2
    err = capsys.readouterr().err
    assert err.startswith("prog: error: File name too long: xxx") and err.count("\n") == 1


def test_runner_names_the_extra_for_a_missing_optional_library(capsys):
    def needs_scipy():
        raise ModuleNotFoundError("No module named 'scipy.ndimage'", name="scipy.ndimage")

    assert run_command("cgvq-study synth", needs_scipy, extra="synth") == 2
    err = capsys.readouterr().err
    assert "needs the [synth] extra (scipy is not installed)" in err
    assert "pip install 'cgvq-toolkit[synth]'" in err


def test_runner_reraises_programming_errors():
    def broken():
        raise ModuleNotFoundError("No module named 'study_app.nothing'", name="study_app.nothing")

    with pytest.raises(ModuleNotFoundError):
        run_command("prog", broken)
    with pytest.raises(ZeroDivisionError):
        run_command("prog", lambda: 1 // 0)


def test_explain_missing_uses_the_module_map():
    exc = explain_missing(ModuleNotFoundError(name="torch"), what="cgvqm score")
    assert isinstance(exc, MissingExtraError) and "[metric]" in str(exc)
    assert explain_missing(ModuleNotFoundError(name="yaml"), what="x") is None


def test_every_package_error_is_a_toolkit_error():
    from analysis.errors import AnalysisError
    from cgvqm_core.errors import CGVQMError
    from session_store.errors import StudyError
    from stimuli_manifests import StimuliError

    for cls in (AnalysisError, CGVQMError, StimuliError, StudyError, TableError):
        assert issubclass(cls, ToolkitError)


@pytest.mark.parametrize("code, says", [
    (errno.ENOSPC, "the disk is full: free some space"),
    (errno.EROFS, "read-only"),
    (errno.EACCES, "check its permissions"),
])
def test_runner_says_what_to_do_about_os_errors_a_user_can_fix(capsys, code, says):
    def fails():
        raise OSError(code, "system text", "/data/P05.sqlite")

    assert run_command("prog", fails) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "/data/P05.sqlite" in err and says in err


def test_a_lock_that_cannot_be_written_names_its_file(tmp_path, monkeypatch):
    """A full disk while the lock file is written: os.write's error carries no file name,
    and the participant read "No space left on device" and nothing else."""
    from stimuli_manifests import file_lock
    from stimuli_manifests.file_lock import FileLock

    def full(fd, data):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(file_lock.os, "write", full)
    lock = FileLock(tmp_path / "P05.sqlite", "P05", busy=lambda holder: "busy")
    with pytest.raises(OSError) as caught:
        lock.acquire()
    assert caught.value.errno == errno.ENOSPC
    assert caught.value.filename == str(tmp_path / "P05.sqlite.lock")
    lock.release()
