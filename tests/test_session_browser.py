"""The operator page as a person uses it: headless Chromium (Debian's) clicks through a session,
the server is killed with SIGKILL and restarted half-way, and its store vanishes for a moment."""

import os
import shutil
import signal

import pytest
from test_session import _free_port, _plan, _server

from goldenticket.session import Session

pytestmark = pytest.mark.browser


@pytest.fixture(scope="module")
def browser():
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    chromium, driver = shutil.which("chromium"), shutil.which("chromedriver")
    if not (chromium and driver):
        pytest.fail("Debian's chromium and chromium-driver are needed: "
                    "apt-get update && apt-get install -y chromium chromium-driver")
    options = webdriver.ChromeOptions()
    options.binary_location = chromium
    for flag in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--window-size=1000,1100"):
        options.add_argument(flag)
    with webdriver.Chrome(service=Service(driver), options=options) as chrome:
        yield chrome


def _shows(chrome, text: str) -> None:
    from selenium.webdriver.support.ui import WebDriverWait

    WebDriverWait(chrome, 10).until(lambda c: text in c.find_element("tag name", "body").text)


def test_an_operator_scores_a_session_in_the_browser(tmp_path, browser):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    Session.new(tmp_path, _plan(tickets=2, episodes_per_ticket=2, confirm=2))  # 4 + 6 episodes
    port = _free_port()
    server = _server(tmp_path, port)
    try:
        browser.get(f"http://127.0.0.1:{port}/")
        _shows(browser, "Episode 0")
        _shows(browser, f"Session {tmp_path.name}, policy p")
        browser.find_element(By.ID, "note").send_keys("clean grasp")
        browser.find_element(By.ID, "success").click()
        _shows(browser, "Episode 1")
        browser.find_element(By.TAG_NAME, "body").send_keys("f")  # keyboard shortcut
        _shows(browser, "Episode 2")
        assert browser.find_element(By.ID, "undo").text == "Undo the score of episode 1 (U)"
        browser.find_element(By.ID, "undo").click()
        _shows(browser, "Score of episode 1 removed")
        browser.find_element(By.ID, "failure").click()
        _shows(browser, "Episode 2")
        os.kill(server.pid, signal.SIGKILL)  # the server dies; what was entered stays
        server.wait()
        server = _server(tmp_path, port)
        browser.refresh()
        _shows(browser, "Episode 2")
        _shows(browser, "2 of 10 episodes scored")
        (tmp_path / "session.sqlite").rename(tmp_path / "away.sqlite")  # the store vanishes: the page says so
        browser.find_element(By.ID, "success").click()
        _shows(browser, "session.sqlite was deleted or replaced while in use")
        (tmp_path / "away.sqlite").rename(tmp_path / "session.sqlite")
        for episode in range(2, 10):
            _shows(browser, f"Episode {episode}")
            browser.find_element(By.ID, "success" if episode % 3 else "failure").click()
        _shows(browser, "Session complete")
        _shows(browser, "Verdict")
        assert len(browser.find_elements(By.CSS_SELECTOR, "#verdict-table tr")) == 4  # header + 3 arms
        assert not browser.find_element(By.ID, "instructions").is_displayed()
        WebDriverWait(browser, 10).until(lambda c: c.execute_script(  # the plot is shown
            "const img = document.querySelector('#verdict img'); return img.complete && img.naturalWidth"))
    finally:
        server.kill()
    scores = Session(tmp_path).scores()
    assert [s["success"] for s in scores[:2]] == [1, 0] and scores[0]["note"] == "clean grasp"
    assert all(s["success"] is not None for s in scores)
    assert (tmp_path / "summary.json").is_file() and (tmp_path / "verdict.png").is_file()


def test_an_operator_sees_what_is_due_and_why_a_sequential_session_stopped(tmp_path, browser):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    Session.new(tmp_path, _plan(stopping="sequential", tickets=3, episodes_per_ticket=2, confirm=6))
    port = _free_port()
    server = _server(tmp_path, port)
    try:
        browser.get(f"http://127.0.0.1:{port}/")
        _shows(browser, "search phase, round 1, 3 tickets left")
        _shows(browser, "0 of at most 18 episodes scored")
        browser.find_element(By.ID, "scene").send_keys("table left")  # kept for every run
        while (status := Session(tmp_path).status())["due"] is not None:
            _shows(browser, f"Episode {status['due']}")
            if status["phase"] == "confirm":
                _shows(browser, "confirm phase, pair")
            arm = Session(tmp_path).episode(status["due"]).ticket_id  # the operator never sees it
            browser.find_element(By.ID, "failure" if arm == "base" else "success").click()
            scored = status["scored"]
            WebDriverWait(browser, 10).until(lambda c, n=scored: Session(tmp_path).status()["scored"] > n)
        _shows(browser, "Session complete")
        _shows(browser, "Stopped: decided early after")
    finally:
        server.kill()
    verdict = Session(tmp_path).verdict()
    assert verdict.stopping.name == "sequential sign test, pairs matched by scene id"
    assert verdict.stopping.test.pairs < 6 and (tmp_path / "summary.json").is_file()
