"""The participant's commands work in the base install: no torch, scipy, pandas, sureal,
pingouin or matplotlib. Each command runs in a subprocess where importing those fails."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from support.lean_install import lean_pythonpath


def lean_env(**extra: str) -> dict[str, str]:
    """Environment of a Python process that looks like the participant's base install."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env.update(PYTHONPATH=lean_pythonpath(), **extra)
    return env


def study(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "cgvq_cli.study_cli", *args], env=lean_env(),
                          capture_output=True, text=True, timeout=120, cwd=cwd)


def test_the_blocker_really_blocks():
    out = subprocess.run([sys.executable, "-c", "import scipy"], env=lean_env(),
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 1 and "No module named 'scipy'" in out.stderr


@pytest.mark.parametrize("command", [[], ["run"], ["export"], ["verify"], ["check"],
                                     ["synth"], ["simulate"]])
def test_help_works_without_the_research_stack(command):
    out = study(*command, "--help")
    assert out.returncode == 0, out.stderr
    assert "usage: cgvq-study" in out.stdout


def test_participant_commands_work_without_the_research_stack(tiny_study, tmp_path):
    from session_store import SessionStore, TrialResult

    check = study("check", str(tiny_study))
    assert check.returncode == 0, check.stderr
    assert "OK" in check.stdout
    from session_store.schedule import make_schedule, schedule_items
    from session_store.study_folder import load_study

    s = load_study(tiny_study)
    path = tiny_study / "sessions" / "P01.sqlite"
    with SessionStore.create(path, participant="P01", study_id=s.manifest.study_id,
                             manifest_sha256=s.loaded.sha256, seed=1, app_version="t",
                             plan=make_schedule(schedule_items(s.manifest), 1, 1)) as store:
        store.record(0, TrialResult(rating=50.0, rt_ms=1.0, n_toggles=0, ms_on_reference=0.0,
                                    ms_on_test=1.0, presented_at="2026-01-01T00:00:00.000Z"))
    export = study("export", str(path), "--csv", "r.csv", cwd=tmp_path)
    assert export.returncode == 0, export.stderr
    zips = list(tmp_path.glob("P01_*.zip"))
    assert len(zips) == 1 and (tmp_path / "r.csv").is_file()
    verify = study("verify", str(zips[0]), str(path))
    assert verify.returncode == 1, verify.stderr  # intact, one of three trials answered
    assert verify.stdout.count("INCOMPLETE") == 2


def test_a_command_needing_an_extra_names_it(tmp_path):
    out = study("synth", "--out", str(tmp_path / "s"), "--no-progress")
    assert out.returncode == 2
    assert out.stderr.count("\n") == 1
    assert "needs the [synth] extra" in out.stderr and "cgvq-toolkit[synth]" in out.stderr


@pytest.mark.parametrize(("entry", "extra"), [("analyze", "analysis"), ("cgvqm", "metric")])
def test_other_console_scripts_name_their_extra_in_the_base_install(entry, extra):
    out = subprocess.run([sys.executable, "-c", f"import cgvq_cli; cgvq_cli.{entry}()",
                          "--help"], env=lean_env(), capture_output=True, text=True, timeout=60)
    assert out.returncode == 2
    assert out.stderr.count("\n") == 1 and f"needs the [{extra}] extra" in out.stderr


def test_console_script_of_the_participant_runs_through_the_launcher():
    out = subprocess.run([sys.executable, "-c", "import sys, cgvq_cli; sys.argv[0] = "
                          "'cgvq-study'; cgvq_cli.study()", "verify", "--help"],
                         env=lean_env(), capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and "usage:" in out.stdout
