"""Makes docs/session.png: a whole sequential session where Meta-World plays the robot and posts
each true outcome through the robot's Client, then the operator page at the end, in Debian's
headless Chromium.

    python docs/session_screenshot.py
"""

import subprocess
import sys
import tempfile
import time
from pathlib import Path

from selenium import webdriver
from selenium.webdriver.chrome.service import Service

from goldenticket.noise import Constant, Gaussian
from goldenticket.policies import load_policy
from goldenticket.rollout import Episode, rollout
from goldenticket.session import Client, Plan, Session
from goldenticket.tasks import get_task

POLICY, TASK, PORT = "metaworld/pick-place-v3/flow", "metaworld/pick-place-v3", 8799


def main() -> None:
    policy, task = load_policy(POLICY), get_task(TASK)
    folder = Path(tempfile.mkdtemp()) / "cup-push"
    Session.new(folder, Plan(POLICY, policy.fingerprint(), policy.noise_shape, 4, 10, 30, 0))
    server = subprocess.Popen([sys.executable, "-m", "goldenticket.cli", "session", "serve", str(folder),
                               "--port", str(PORT)])
    try:
        robot = Client(f"http://127.0.0.1:{PORT}")  # waits for the server to start
        while (due := robot.next()) is not None:
            source = Gaussian(0) if due.noise is None else Constant(due.noise)
            result = rollout(policy, task, [Episode(source, due.episode)])[0]
            robot.score(due.episode, result.success)
        options = webdriver.ChromeOptions()
        options.binary_location = "/usr/bin/chromium"
        for flag in ("--headless=new", "--no-sandbox", "--window-size=900,1350"):
            options.add_argument(flag)
        with webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=options) as chrome:
            chrome.get(f"http://127.0.0.1:{PORT}/")
            time.sleep(2)
            chrome.save_screenshot(str(Path(__file__).parent / "session.png"))
    finally:
        server.kill()



if __name__ == "__main__":
    main()
