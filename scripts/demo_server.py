"""The demo's data collection through the study server, as an experimenter would run it.

``cgvq-study serve`` on 127.0.0.1 -> ``cgvq-study invite`` -> the simulated participants rate
and upload at once through the app's upload client (``cgvq-study simulate --server``), one of
them offline for a while, while the server is killed (SIGKILL) and restarted once -> a
dashboard screenshot (headless Chromium, when Selenium and chromium-driver are installed) ->
``cgvq-study pull`` of every session as received. The dashboard URL is printed while it runs.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

from study_server.auth import command_line_token
from study_server.child import ServeProcess

REPO = Path(__file__).resolve().parents[1]
CHROMEDRIVER = Path("/usr/bin/chromedriver")
CHROMIUM = Path("/usr/bin/chromium")
HEADLESS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
            "--disable-background-networking", "--disable-component-update", "--disable-sync",
            "--no-first-run")


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "cgvq_cli.study_cli", *args]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _dashboard_html(url: str, token: str) -> str:
    req = urllib.request.Request(url + "/dashboard",
                                 headers={"Authorization": f"Bearer {token}"})
    with urllib.request.urlopen(req, timeout=30) as resp:
        return resp.read().decode("utf-8")


def _wait_for_statistics(url: str, token: str, n_ratings: int, timeout: float) -> bool:
    """Until the dashboard's statistics cover every rating (they run in the background)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        html = _dashboard_html(url, token)
        m = re.search(r"on (\d+) ratings", html)
        if m and int(m.group(1)) >= n_ratings and "dmos-figure" in html:
            return True
        time.sleep(2.0)
    return False


def missing_browser() -> str | None:
    """None when Selenium, Chromium and chromium-driver are installed, else what is missing."""
    try:
        import selenium  # noqa: F401 - only whether it is there
    except ImportError:
        return "Selenium is not installed (pip install '.[dev]')"
    if not (CHROMEDRIVER.exists() and CHROMIUM.exists()):
        return "chromium and chromium-driver are not installed (make system-deps)"
    return None


def headless_chromium(width: int, height: int):
    """Debian's Chromium, headless, driven by Selenium with an explicit driver path (nothing
    downloads a driver); the caller quits it. Also the browser of the dashboard's tests."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = str(CHROMIUM)
    for flag in HEADLESS:
        options.add_argument(flag)
    options.add_argument(f"--window-size={width},{height}")
    driver = webdriver.Chrome(service=Service(executable_path=str(CHROMEDRIVER)),
                              options=options)
    driver.set_page_load_timeout(60)
    return driver


def screenshot(url: str, token: str, path: Path) -> str | None:
    """The dashboard as a PNG through headless Chromium; None, or why it was not taken."""
    why = missing_browser()
    if why:
        return why
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support import expected_conditions
    from selenium.webdriver.support.ui import WebDriverWait

    driver = headless_chromium(1500, 1200)
    try:
        driver.get(url + "/dashboard")
        driver.find_element(By.ID, "token").send_keys(token)
        driver.find_element(By.ID, "login").click()
        # the login answers with a redirect to the dashboard: wait for it on a busy machine
        WebDriverWait(driver, 60).until(
            expected_conditions.presence_of_element_located((By.ID, "participants")))
        height = driver.execute_script("return document.body.scrollHeight")
        driver.set_window_size(1500, int(height) + 150)
        driver.save_screenshot(str(path))
    finally:
        driver.quit()
    return None


def collect(study: Path, out: Path, *, raters: int, outliers: int, seed: int, log: list[dict],
            run, stagger: float = 0.0, after_refit: bool = False
            ) -> tuple[Path, Path, dict]:
    """Serve ``study``, let the simulated panel upload, pull. Returns (folder of pulled
    session files, the simulation's truth file, facts for the summary)."""
    token = command_line_token(24)
    env = {**os.environ, "CGVQ_ADMIN_TOKEN": token, "PYTHONPATH": str(REPO)}
    port = _free_port()
    url = f"http://127.0.0.1:{port}"
    invites = out / "invites.csv"
    invites.unlink(missing_ok=True)
    state = study / "server"
    if state.exists():  # a previous demo in the same folder
        for p in sorted(state.rglob("*"), reverse=True):
            p.unlink() if p.is_file() else p.rmdir()
    res = run("invite", _cli("invite", str(study), "--n", str(raters), "--out", str(invites),
                             "--server", url), log)
    if res.returncode:
        raise SystemExit(1)
    server = ServeProcess(study, ["--stats-every", "5"], port=port, env=env, cwd=REPO)
    t0 = time.monotonic()
    server.start(timeout=120.0)
    print(f"\n>>> the study server runs at {server.url}; watch it live: {server.url}/dashboard "
          f"(admin token {token})\n", flush=True)
    local = out / "participants"
    offline = f"P03:2:{8 + raters // 4}"
    facts: dict = {"url": server.url, "offline_participant": offline, "restarts": 0}
    sim = subprocess.Popen(
        _cli("simulate", "--manifest", str(study / "manifest.json"), "--raters", str(raters),
             "--outliers", str(outliers), "--seed", str(seed), "--out", str(local),
             "--colour-failures", "1",
             "--overwrite", "--server", server.url, "--invites", str(invites), "--pace",
             "0.04", "--offline", offline, "--stagger", str(stagger), "--no-progress",
             *(["--after-refit"] if after_refit else [])),
        env=env, cwd=REPO)
    try:
        time.sleep(5.0)
        if sim.poll() is None:  # mid-study: the server dies and comes back
            print(">>> killing the study server (SIGKILL) mid-study, restarting it in 3 s",
                  flush=True)
            server.kill()
            time.sleep(3.0)
            server.start(timeout=120.0)
            facts["restarts"] = 1
            print(f">>> the study server is back at {server.url}/dashboard", flush=True)
        code = sim.wait(timeout=1800)
    except BaseException:
        sim.kill()
        server.stop()
        raise
    log.append({"step": "simulate through the server", "seconds":
                round(time.monotonic() - t0, 1), "returncode": code,
                "error": None if code == 0 else "not every upload arrived"})
    if not (local / "ground_truth.json").is_file():  # simulate stopped early (its stderr)
        server.stop()
        raise SystemExit(1)
    try:
        truth = json.loads((local / "ground_truth.json").read_text())
        per = truth.get("trials_per_participant",
                        truth["repetitions"] * len(truth["stimuli"]))
        n = sum(1 for _ in truth["raters"]) * per
        if _wait_for_statistics(server.url, token, n, timeout=300):
            why = screenshot(server.url, token, out / "dashboard.png")
            facts["dashboard_png"] = None if why else str(out / "dashboard.png")
            if why:
                print(f"  (no dashboard screenshot: {why})", flush=True)
        pulled = out / "pulled"
        shutil.rmtree(pulled, ignore_errors=True)  # an earlier demo's files are not this one's
        res = run("pull", _cli("pull", server.url, "--admin-token", token, "--out",
                               str(pulled), "--csv", str(out / "ratings.csv")), log)
        if res.returncode:
            raise SystemExit(1)
        listing = json.loads((pulled / "server_listing.json").read_text())
        facts["sessions_pulled"] = len(list(pulled.glob("*.sqlite")))
        facts["flags"] = {p["participant"]: [f["kind"] for f in p["flags"]]
                          for p in listing["participants"] if p["flags"]}
        facts["all_arrived"] = code == 0
    finally:
        server.stop()
    return pulled, local / "ground_truth.json", facts
