"""The participant's side of uploads and downloads runs on the standard library: in a
process where the research stack and the server's libraries cannot be imported, a session
uploads and the study downloads."""

from __future__ import annotations

import subprocess
import sys

from .conftest import REPO, write_session

LEAN = """
import importlib.abc, sys
BLOCKED = ("torch", "scipy", "pandas", "sureal", "pingouin", "matplotlib", "starlette",
           "uvicorn", "jinja2", "fastapi", "httpx", "requests", "anyio", "pygame", "moderngl")
class Absent(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname, path=None, target=None):
        if fullname.split(".")[0] in BLOCKED:
            raise ModuleNotFoundError(fullname, name=fullname)
sys.meta_path.insert(0, Absent())
from study_app.remote import ServerClient, sync_session
from study_app.remote.download import download_study, study_plan, check_disk_space
url, token, session, cache = sys.argv[1:5]
client = ServerClient(url, token)
result = sync_session(session, client, "P01")
plan = study_plan(client, "P01", cache)
check_disk_space(plan)
download_study(client, "P01", plan)
print("synced", result.acked_seq, result.local_seq, "downloaded", len(plan.files))
print("loaded", sorted(m for m in sys.modules if m.split(".")[0] in BLOCKED))
"""


def test_upload_and_download_without_research_stack_or_server_libraries(
        served_study, tmp_path, invites, server_factory):
    [inv] = invites(1)
    srv = server_factory(served_study)
    session = tmp_path / "P01.sqlite"
    write_session(served_study, session, "P01", ratings=5).close()
    proc = subprocess.run(
        [sys.executable, "-c", LEAN, srv.url, inv.token, str(session), str(tmp_path / "c")],
        env={"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin"}, capture_output=True,
        text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    n = lines[0].split()
    assert n[0] == "synced" and n[1] == n[2] and int(n[1]) > 5
    assert lines[1] == "loaded []"
