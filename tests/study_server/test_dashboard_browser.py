"""The dashboard in a real headless browser (Debian's Chromium and chromium-driver, driven
by Selenium with an explicit driver path: nothing downloads a driver)."""

from __future__ import annotations

import importlib.util
import shutil
import time
from pathlib import Path
from types import ModuleType

import pytest

from study_app.simulate import SimulationOptions, UploadOptions, run_simulation

from .conftest import ADMIN, ARTIFACTS, REPO, make_served_study, replace_a_video


def _demo_server() -> ModuleType:
    """scripts/demo_server.py (a program, not a package), whose browser launcher is reused."""
    spec = importlib.util.spec_from_file_location("demo_server",
                                                  REPO / "scripts" / "demo_server.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture
def browser():
    demo_server = _demo_server()
    why = demo_server.missing_browser()
    if why:
        pytest.skip(why)
    driver = demo_server.headless_chromium(1500, 1900)
    yield driver
    driver.quit()


def dashboard_study(tmp_path: Path) -> Path:
    return make_served_study(tmp_path / "study", refs=4, conds=3, repetitions=2,
                             file_bytes=256)


def _log_in_and_wait_for_statistics(browser, ratings: int, figure: bool = True) -> None:
    """Log in on the open login page, then reload until the statistics on ``ratings`` ratings
    (and the figure, when ``figure``) show. The page itself reloads only every 30 s."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support import expected_conditions as ec
    from selenium.webdriver.support.ui import WebDriverWait

    browser.find_element(By.ID, "token").send_keys(ADMIN)
    browser.find_element(By.ID, "login").click()
    WebDriverWait(browser, 30).until(ec.presence_of_element_located((By.ID, "participants")))
    deadline = time.monotonic() + 120  # the statistics arrive in the background

    def shown() -> bool:
        return (f"on {ratings} ratings" in browser.find_element(By.ID, "stats-age").text
                and (not figure or bool(browser.find_elements(By.ID, "dmos-figure"))))

    while not shown():
        assert time.monotonic() < deadline, "statistics never computed"
        time.sleep(0.5)
        browser.refresh()


def _full_page_screenshot(browser, name: str) -> Path:
    ARTIFACTS.mkdir(exist_ok=True)
    browser.set_window_size(1500, browser.execute_script(
        "return document.body.scrollHeight") + 150)
    shot = ARTIFACTS / name
    assert browser.save_screenshot(str(shot))
    return shot


@pytest.mark.slow  # about 11 s here: CI runs it after `make test` (.ci/run)
def test_dashboard_in_a_real_browser(browser, tmp_path, invites, server_factory):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support import expected_conditions as ec
    from selenium.webdriver.support.ui import WebDriverWait

    study = dashboard_study(tmp_path)
    inv = invites(9, study=study)
    srv = server_factory(study, "--stats-every", "1", "--target-raters", "10")
    result = run_simulation(
        study / "manifest.json", tmp_path / "local",
        SimulationOptions(raters=7, outliers=1, outlier_kind="inverted", seed=3),
        progress=False, upload=UploadOptions(srv.url, {i.participant: i.token
                                                       for i in inv[:7]}))
    assert all(s.all_arrived for s in result.upload.values())
    # P08 has not started, but its app reported a skewed clock and an edited file
    from datetime import UTC, datetime, timedelta

    from session_store.protocol import PROTOCOL
    from study_app.remote import ServerClient

    ServerClient(srv.url, inv[7].token).json("POST", "/api/v1/participants/P08/handshake", {
        "protocol": PROTOCOL, "session_id": None, "app_version": "t", "log_hashes": [],
        "client_time": (datetime.now(UTC) - timedelta(minutes=7)).isoformat(),
        "local_problems": ["table ratings differs from the change log (edited outside the "
                           "app)"]})
    # P09 rated 3 trials and withdrew in the app: their data stay until 'withdraw'
    from study_app.remote import sync_session

    from .conftest import write_session

    store = write_session(study, tmp_path / "P09.sqlite", "P09", ratings=3)
    store.withdraw("changed my mind")
    store.close()
    sync_session(tmp_path / "P09.sqlite", ServerClient(srv.url, inv[8].token), "P09")
    browser.get(srv.url + "/dashboard")
    assert "Admin token" in browser.page_source  # asks once
    browser.find_element(By.ID, "token").send_keys("wrong-token-12345678")
    browser.find_element(By.ID, "login").click()
    # the click only starts the form post: wait for the answer page, not the old one
    message = WebDriverWait(browser, 30).until(
        ec.presence_of_element_located((By.ID, "login-message")))
    assert "That is not the admin token" in message.text
    _log_in_and_wait_for_statistics(browser, 7 * 32)
    rows = browser.find_elements(By.CSS_SELECTOR, "#participants tr[data-participant]")
    assert len(rows) == 9
    assert "data still stored: P09" in browser.find_element(By.ID, "withdrew-in-app").text
    text = {r.get_attribute("data-participant"): r.text for r in rows}
    assert "finished" in text["P01"] and "32 / 32" in text["P01"]
    assert "seen, no session yet" in text["P08"] and "clock_skew" in text["P08"]
    flags = browser.find_element(By.ID, "flags").text
    assert "7 min behind the server's" in flags and "edited outside the app" in flags
    outlier = next(p for p, t in text.items() if "remove" in t)
    assert outlier.startswith("P")
    # the list above the table names who needs a look and why; a name jumps to the row
    look = browser.find_element(By.ID, "attention").text
    assert f"{outlier}: screening would remove; r panel -" in look
    assert "P08: session file edited on the computer" in look  # words, not codes
    assert "clock far off" not in look  # a clock the server corrected needs nobody's look
    assert "participants to look at" in look
    marked = {r.get_attribute("data-participant") for r in
              browser.find_elements(By.CSS_SELECTOR, "#participants tr.look")}
    assert {outlier, "P08"} <= marked and "P01" not in marked
    # ordered by attention, the marked rows come first (the reload keeps the order's query)
    browser.get(srv.url + "/dashboard?order=look")
    looked = [r.get_attribute("data-participant") for r in
              browser.find_elements(By.CSS_SELECTOR, "#participants tr[data-participant]")]
    assert set(looked[:len(marked)]) == marked and len(looked) == 9
    assert "those to look at first" in browser.find_element(By.CSS_SELECTOR,
                                                            "#order strong").text
    browser.get(srv.url + "/dashboard?order=nonsense")  # an unknown order is the default
    assert browser.find_element(By.CSS_SELECTOR, "#order strong").text == "by participant"
    assert browser.find_element(By.ID, "n-ratings").text == str(7 * 32)
    icc = float(browser.find_element(By.ID, "icc").text)
    assert 0.5 < icc <= 1.0
    # the ceiling as the report gives it: Spearman-Brown and its square root
    card = browser.find_element(By.XPATH, "//*[contains(text(), 'split-half PLCC')]").text
    sb = float(card.split("Spearman-Brown ")[1].split(";")[0])
    assert f"ceiling for a metric {sb ** 0.5:.3f}"[:-1] in card  # last digit: rounding
    # the figure really loaded (the cookie authenticates the image too)
    loaded = browser.execute_script(
        "const i = document.getElementById('dmos-figure'); return i.complete && "
        "i.naturalWidth;")
    assert loaded and loaded > 200
    # times were turned into local time by the page's script (no ISO 'Z' left)
    first_time = browser.find_element(By.CSS_SELECTOR, "#flags time")
    assert first_time.text and not first_time.text.endswith("Z")
    shot = _full_page_screenshot(browser, "dashboard.png")
    shutil.copy(shot, tmp_path / "dashboard.png")


# about 9 s: CI runs it after `make test` (.ci/run), as `make test-slow` does
@pytest.mark.slow
def test_the_dashboard_after_a_new_version_counts_only_its_sessions(
        browser, tmp_path, invites, server_factory):
    """Two participants rate version 1, two more the version served after ``--new-version``:
    the statistics are on the second pair, and the page says where the other ratings went."""
    from selenium.webdriver.common.by import By

    study = dashboard_study(tmp_path)
    tokens = {i.participant: i.token for i in invites(4, study=study)}
    halves = [dict(list(tokens.items())[:2]), dict(list(tokens.items())[2:])]
    for version, (args, half) in enumerate(zip(([], ["--new-version"]), halves, strict=True)):
        if version:
            replace_a_video(study)
        srv = server_factory(study, "--stats-every", "1", *args)
        run_simulation(study / "manifest.json", tmp_path / f"local{version}",
                       SimulationOptions(raters=2, seed=version + 1), progress=False,
                       upload=UploadOptions(srv.url, half, timeout_s=120))
        if not version:
            srv.stop()
    browser.get(srv.url + "/dashboard")
    per_session = 32  # 4 scenes x (3 conditions + hidden reference) x 2 repetitions
    # the statistics are on version 2's raters; two are too few for DMOS and its figure
    _log_in_and_wait_for_statistics(browser, 2 * per_session, figure=False)
    assert browser.find_element(By.ID, "n-ratings").text == str(4 * per_session)
    assert browser.find_element(By.ID, "n-ratings-earlier").text == str(2 * per_session)
    assert browser.find_element(By.ID, "other-versions").text.startswith(
        "2 participant(s) rated an earlier version")
    versions = [r.find_elements(By.TAG_NAME, "td")[1].text for r in
                browser.find_elements(By.CSS_SELECTOR, "#participants tr[data-participant]")]
    assert sorted(versions) == ["v1", "v1", "v2", "v2"]
    _full_page_screenshot(browser, "dashboard_new_version.png")


@pytest.mark.slow  # about 12 s here: CI runs it after `make test` (.ci/run)
def test_the_page_survives_a_server_outage_and_recovers(browser, tmp_path, invites,
                                                         server_factory):
    """While the server is down the page keeps what it showed under a banner saying since
    when; once the server is back (same port) it reloads by itself. The page polls every
    30 s; the test makes its script poll every second."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    study = dashboard_study(tmp_path)
    invites(2, study=study)
    srv = server_factory(study, "--stats-every", "1")
    browser.get(srv.url + "/dashboard")
    browser.find_element(By.ID, "token").send_keys(ADMIN)
    browser.find_element(By.ID, "login").click()
    WebDriverWait(browser, 30).until(lambda b: b.find_elements(By.ID, "participants"))
    port, url = srv.port, srv.url
    srv.stop()
    browser.execute_script("every = 1; check();")
    banner = WebDriverWait(browser, 30).until(lambda b: b.find_elements(By.ID, "unreachable"))
    assert banner[0].text.startswith("The study server cannot be reached (its last answer "
                                     "came at ")  # the page's time, not the first failed try
    assert "no answer since" in banner[0].text
    assert "stale" in browser.find_element(By.TAG_NAME, "body").get_attribute("class")
    assert "tries again every 1 s" in banner[0].text
    assert len(browser.find_elements(By.CSS_SELECTOR, "#participants tr[data-participant]")) == 2
    _full_page_screenshot(browser, "dashboard_server_unreachable.png")
    again = server_factory(study, "--stats-every", "1", port=port)
    assert again.url == url
    # the reload is a fresh page: no banner, the table again (the cookie survived the restart)
    WebDriverWait(browser, 60).until(lambda b: not b.find_elements(By.ID, "unreachable")
                                     and b.find_elements(By.ID, "participants"))
