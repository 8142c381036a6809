"""The end screen tells the participant what to send, so the session file must be whole before
it shows. Checkpoints postponed during the session (the upload client reading the file) leave
ratings in the ``-wal``; when the last checkpoint then fails (a full disk), the ratings are in
the file and its ``-wal`` together, and the screen must name both files instead of saying
"send only this file" (it used to, and the error line came only after the window closed)."""

from __future__ import annotations

import shutil
import sqlite3
from pathlib import Path

import numpy as np
import pytest
from support.sessions import plain_result

from session_store import SessionStore, read_session
from session_store.schedule import make_schedule, schedule_items
from session_store.study_folder import load_study
from study_app.app import App, RunOptions
from study_app.screens import content
from study_app.screens.markdown import parse_markdown

REPO = Path(__file__).resolve().parents[2]


def names(keys, action):
    return keys.label(action)


class _Disk:
    """The store's connection, whose checkpoints fail as SQLite's do while a reader holds
    the file (``busy``: postponed) or on a full disk (``full``)."""

    def __init__(self, con: sqlite3.Connection) -> None:
        self._con, self.mode = con, "busy"

    def execute(self, sql: str, *args: object) -> sqlite3.Cursor:
        if sql.startswith("PRAGMA wal_checkpoint"):
            full = self.mode == "full"
            exc = sqlite3.OperationalError("database or disk is full" if full
                                           else "database is locked")
            exc.sqlite_errorcode = sqlite3.SQLITE_FULL if full else sqlite3.SQLITE_BUSY
            raise exc
        return self._con.execute(sql, *args)

    def __getattr__(self, name: str) -> object:
        return getattr(self._con, name)


def _finished_app(tiny_study, *, full_disk: bool) -> tuple[App, list]:
    """A finished session of P07, its checkpoints postponed throughout when ``full_disk``
    (the last one then fails for lack of space), and the app about to show its end."""
    study = load_study(tiny_study)
    app = App(study, RunOptions(participant="P07"))
    plan = make_schedule(schedule_items(study.manifest), 1, 3)
    store = SessionStore.create(app.session_path, participant="P07",
                                study_id=study.manifest.study_id,
                                manifest_sha256=study.loaded.sha256, seed=3, app_version="t",
                                plan=plan)
    disk = _Disk(store._con)
    if full_disk:
        store._con = disk  # type: ignore[assignment]
    for trial in plan:
        store.record(trial.index, plain_result(50.0))
    store.finish()
    disk.mode = "full"
    shown: list = []
    app.store = store
    app._name_keys = names  # type: ignore[method-assign]
    app._screen = lambda spec: shown.append(spec) or "close"  # type: ignore[method-assign]
    return app, shown


def _alone(path: Path, tmp_path: Path) -> Path:
    """A copy of the session file without its -wal: what the experimenter gets when the
    participant sends the one file."""
    copy = tmp_path / "alone" / path.name
    copy.parent.mkdir()
    shutil.copy(path, copy)
    return copy


def test_a_failed_last_checkpoint_makes_the_end_screen_name_both_files(tiny_study, tmp_path):
    app, shown = _finished_app(tiny_study, full_disk=True)
    n = len(app.store.plan())
    app._end_screen(n, withdrawn=False)
    (spec,) = shown
    flat = "".join(b.text for b in parse_markdown(spec.body))
    path = app.session_path.resolve()
    assert str(path) in flat and f"{path}-wal" in flat
    assert "Send these two files" in spec.body and "Send only this file" not in spec.body
    # What the screen says is true: the file alone lacks ratings that the pair holds.
    alone = read_session(_alone(app.session_path, tmp_path))
    assert len(alone.ratings) < n
    app.store._con = app.store._con._con
    app.store.close()
    assert len(read_session(app.session_path).ratings) == n


def test_a_whole_file_keeps_the_one_file_end_screen(tiny_study, tmp_path):
    app, shown = _finished_app(tiny_study, full_disk=False)
    n = len(app.store.plan())
    app._end_screen(n, withdrawn=False)
    (spec,) = shown
    assert "Send only this file" in spec.body and "-wal" not in spec.body
    assert len(read_session(_alone(app.session_path, tmp_path)).ratings) == n
    app.store.close()


def test_end_screen_text_for_two_files_with_and_without_an_upload(tmp_path):
    path = tmp_path / "sessions" / "P_01.sqlite"
    spec = content.end(path, 240, False, names, in_two_files=True)
    flat = "".join(b.text for b in parse_markdown(spec.body))
    assert str(path.resolve()) in flat and f"{path.resolve()}-wal" in flat
    assert "Do not delete or rename either of them" in spec.body
    arrived = content.end(path, 240, False, names, upload=(True, "Everything arrived."),
                          in_two_files=True)
    assert "There is nothing to send" in arrived.body and "Keep both files together" in \
        arrived.body


def test_two_files_end_screen_screenshot(egl, tmp_path):
    """The screen as the player draws it (off-screen), saved for a person to look at:
    test-artifacts/study_app/screens/end-two-files.png."""
    spec = content.end(tmp_path / "sessions" / "P07.sqlite", 240, False, names,
                       in_two_files=True)
    _shot(spec, "end-two-files")


@pytest.mark.parametrize(("withdrawn", "name"), [(False, "end-offline"),
                                                 (True, "end-withdrawn-offline")])
def test_offline_end_screens_screenshot(egl, tmp_path, withdrawn, name):
    """A served session whose last answers (or whose withdrawal) have not reached the server:
    starting again is the instruction, the file by e-mail the fallback. Saved for a person
    to look at: test-artifacts/study_app/screens/end-offline*.png."""
    from study_app.remote import UploadStatus

    pending = (("withdrawn", 1),) if withdrawn else (("event", 1), ("rating", 3))
    status = UploadStatus("offline", 9, 13, "cannot reach the study server "
                          "https://study.example.org:8443 (connection refused)",
                          pending=pending)
    spec = content.end(tmp_path / "sessions" / "P07.sqlite", 240, withdrawn, names,
                       upload=(False, status.describe()))
    assert ("withdrawal has not reached" in spec.body) == withdrawn
    assert "## If you cannot start the study again" in spec.body
    _shot(spec, name)


def _shot(spec, name: str) -> None:
    """Draw ``spec`` off-screen as the player does and save it under test-artifacts."""
    import moderngl
    from PIL import Image

    from study_app.fonts import Fonts
    from study_app.layout import text_screen_layout
    from study_app.render import MID_GREY, Renderer
    from study_app.screens.draw import draw_text_screen
    from study_app.screens.textflow import flow_blocks

    size = (1280, 800)
    ctx = moderngl.create_standalone_context(backend="egl", require=330)
    try:
        fbo = ctx.simple_framebuffer(size)
        fbo.use()
        fonts = Fonts()
        renderer = Renderer(ctx, size, fonts)

        def clear(color=MID_GREY):  # the renderer clears the window; here the framebuffer
            fbo.use()
            ctx.clear(*color)

        renderer.clear = clear  # type: ignore[method-assign]
        lay = text_screen_layout(size, fonts, title=spec.title, buttons=spec.buttons)
        flow = flow_blocks(parse_markdown(spec.body), lay.column.w, fonts, px=lay.px)
        draw_text_screen(renderer, lay, flow, 0, primary=spec.primary)
        pixels = np.frombuffer(fbo.read(components=3, alignment=1), np.uint8)
        image = pixels.reshape(size[1], size[0], 3)[::-1]
    finally:
        ctx.release()
    out = REPO / "test-artifacts" / "study_app" / "screens" / f"{name}.png"
    out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(image).save(out)
    assert len(np.unique(image.reshape(-1, 3), axis=0)) > 2  # text was drawn
