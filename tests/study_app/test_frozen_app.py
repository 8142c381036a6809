"""The frozen participant app (``make participant-app``) runs a whole study under Xvfb.

Built by PyInstaller from the base install only, it must work without any Python on the
machine: the test runs ``dist/cgvq-study/cgvq-study`` with a bare environment (no PYTHONPATH,
no virtual environment on PATH) through display check, briefing, consent, three trials and
the end screen, then checks the session file it wrote. Slow (it needs the build first); CI
builds the app and runs it.
"""

from __future__ import annotations

import os
import re
import subprocess
from pathlib import Path

import pytest

from session_store import read_session, verify_session

pytestmark = [pytest.mark.gui, pytest.mark.slow]

REPO = Path(__file__).resolve().parents[2]
APP = REPO / "dist" / "cgvq-study" / "cgvq-study"


@pytest.fixture(scope="module")
def frozen_app() -> Path:
    if not APP.is_file():
        pytest.skip("the frozen app is not built: run 'make participant-app' first")
    return APP


def _bare(env: dict[str, str]) -> dict[str, str]:
    keep = ("DISPLAY", "SDL_VIDEODRIVER", "SDL_AUDIODRIVER", "HOME", "LANG", "TMPDIR")
    return {k: v for k, v in env.items() if k in keep} | {"PATH": "/usr/bin:/bin"}


def test_frozen_app_size_and_help(frozen_app):
    size = sum(f.stat().st_size for f in frozen_app.parent.rglob("*")
               if f.is_file() and not f.is_symlink())
    assert size < 250 * 1024**2, f"{size / 1024**2:.0f} MB"
    out = subprocess.run([str(frozen_app), "--help"], env=_bare(dict(os.environ)),
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and "run" in out.stdout and "synth" not in out.stdout
    notices = frozen_app.parent / "licenses"
    assert (notices / "NOTICE.md").is_file() and (notices / "av").is_dir()


def test_frozen_app_runs_a_study_end_to_end(tmp_path, xdisplay, study_factory, app_driver,
                                            frozen_app):
    study = study_factory(tmp_path / "study")
    app = app_driver(_bare(xdisplay), [str(study), "--participant", "P01", "--practice", "0",
                                       "--max-dropped-frames", "-1", "--pilot-no-vsync"],
                     command=[str(frozen_app)])
    app.wait("preflight-passed", timeout=90)
    app.key("space")
    app.wait("welcome")
    app.key("space")
    app.wait("consent")
    app.key("End", "a")
    for trial in range(3):
        app.wait(f"viewing trial={trial}")
        line = app.open_rating()
        assert re.search(r"slider=", line)
        app.key("Right", "Return")
        app.wait(f"recorded trial={trial}")
    app.wait("end")
    app.key("Return")
    code, out = app.finish(timeout=60)
    assert code == 0, out
    session = study / "sessions" / "P01.sqlite"
    record = read_session(session)
    assert [r["rating"] for r in record.ratings] == [50.0, 50.0, 50.0]
    assert record.info.settings["timing_mode"] == "paced-pilot"
    assert verify_session(session).complete
