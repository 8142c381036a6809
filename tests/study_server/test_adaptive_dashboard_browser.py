"""The dashboard of an adaptive study with a stopping target, in a real headless browser:
the allocation policy, the target, the current widths and the participants still needed
(screenshot kept as an artifact)."""

from __future__ import annotations

import re
import time

import pytest

from study_app.simulate import SimulationOptions, UploadOptions, run_simulation

from .conftest import ADMIN, ARTIFACTS
from .test_adaptive_allocation import _adaptive_study
from .test_dashboard_browser import browser  # noqa: F401  (the fixture)


@pytest.mark.slow  # about 13 s: CI runs it after `make test` (.ci/run), as does `make test-slow`
def test_the_dashboard_shows_design_target_widths_and_projection(browser, tmp_path,  # noqa: F811
                                                                  invites, server_factory):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support import expected_conditions as ec
    from selenium.webdriver.support.ui import WebDriverWait

    study = _adaptive_study(tmp_path / "adaptive")
    inv = invites(8, study=study)
    srv = server_factory(study, "--stats-every", "1", "--target-mean-ci", "5",
                         "--target-max-ci", "9")
    for group, seed in ((inv[:3], 1), (inv[3:6], 2)):  # two waves: the widths shrink
        run = run_simulation(study / "manifest.json", tmp_path / f"local{seed}",
                             SimulationOptions(raters=3, seed=seed), progress=False,
                             upload=UploadOptions(srv.url, {i.participant: i.token
                                                            for i in group}))
        assert all(s.all_arrived for s in run.upload.values())
        deadline = time.monotonic() + 120  # the statistics record this wave's widths
        while not any(h[0] == 3 * seed for h in _history(study)):
            assert time.monotonic() < deadline, _history(study)
            time.sleep(0.5)
    browser.get(srv.url + "/dashboard")
    browser.find_element(By.ID, "token").send_keys(ADMIN)
    browser.find_element(By.ID, "login").click()
    WebDriverWait(browser, 30).until(ec.presence_of_element_located((By.ID, "design")))
    deadline = time.monotonic() + 120
    while "raters" not in browser.find_element(By.ID, "design").text or \
            "6 raters" not in browser.find_element(By.ID, "design").text:
        assert time.monotonic() < deadline, browser.find_element(By.ID, "design").text
        time.sleep(1.0)
        browser.refresh()
    design = browser.find_element(By.ID, "design").text
    assert "Allocation: adaptive (3 blocks per session" in design
    assert "Target: mean DMOS 95 % CI width <= 5 and widest DMOS 95 % CI <= 9" in design
    widths = browser.find_element(By.ID, "widths").text
    mean_now = float(re.search(r"mean DMOS 95% CI width ([\d.]+)", widths).group(1))
    assert 0 < mean_now < 100
    projected = browser.find_element(By.ID, "projected").text
    more = int(re.search(r"About (\d+) more rater", projected).group(1))
    history = _history(study)  # one point per number of raters, the last with all six
    assert history[-1][0] == 6 and len(history) >= 2 and more >= 0
    ARTIFACTS.mkdir(exist_ok=True)
    browser.set_window_size(1500, browser.execute_script(
        "return document.body.scrollHeight") + 150)
    assert browser.save_screenshot(str(ARTIFACTS / "dashboard_adaptive.png"))


def _history(study):
    import sqlite3

    con = sqlite3.connect(f"file:{study / 'server' / 'state.sqlite'}?mode=ro", uri=True)
    try:
        return con.execute("SELECT raters, ratings, mean_width, max_width FROM "
                           "stopping_history ORDER BY raters").fetchall()
    finally:
        con.close()
