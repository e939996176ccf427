"""Shared by the perceive tests: a tiny study prepared once, the real server as a process, and a
headless Chromium driven by Selenium (Debian's chromium and chromium-driver)."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

REPO = Path(__file__).resolve().parents[2]

TINY_STUDY = """
[study]
name = "vcv-tiny"
design = "intelligibility"
seed = 7
title = "Tiny <VCV> study"
consent = "You will see a face <script>alert(1)</script> speak.\\n\\nYour answers are stored under a pseudonym."
attention_every = 3
completion_code = "DONE-42"

[stimuli]
items = ["aba", "ava"]
snr_db = [0.0]
fps = 10
size_px = 64
render = "2d"  # the server is under test here; the 3-D face's videos are test_perceive_face's

[[condition]]
name = "coarticulation"

[[condition]]
name = "keyframe"
face = "step"
"""


def write_spec(directory: Path, text: str = TINY_STUDY) -> Path:
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / "study.toml"
    path.write_text(text, encoding="utf-8")
    return path


class Server:
    """`coartic perceive serve` as a child process (so that it can be killed like a crashed server)."""

    def __init__(self, study: Path, db: str, port: int = 0) -> None:
        env = {**os.environ, "PYTHONPATH": str(REPO / "python")}
        # SIGINT at its default in the server, whatever pytest inherited: a shell without job control
        # starts background commands (`make test &` in a script) with SIGINT ignored, Python then
        # installs no KeyboardInterrupt for it, and stop() waited out its 30 s for every server
        self.proc = subprocess.Popen([sys.executable, "-m", "coartic.cli", "perceive", "serve", str(study),
                                      "--db", db, "--port", str(port)], stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True, env=env,
                                     preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()  # blocks until the socket listens (or the process ends)
        if "serving" not in line:
            err = self.proc.stderr.read() if self.proc.stderr else ""
            raise RuntimeError(f"the server did not start: {line!r} {err}")
        self.url = line.split(" at ", 1)[1].split(" ", 1)[0]
        self.port = int(self.url.rsplit(":", 1)[1].strip("/"))

    def kill(self) -> None:
        """SIGKILL: no handler runs, as when the machine or the process dies."""
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(timeout=30)
        for f in (self.proc.stdout, self.proc.stderr):
            if f is not None:
                f.close()

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.kill()
                return
        for f in (self.proc.stdout, self.proc.stderr):
            if f is not None:
                f.close()


class AppServer:
    """The study's pages (coartic.perceive.server.create_app, the app `coartic perceive serve` serves)
    on a free local port, from a thread of the test process, with `Server`'s url and stop(). For the
    tests of the pages and the answers: the server process itself (its start, a crash, waitress) is
    `Server`'s test; starting one costs a CPU-second and 2-3 s of wall for the interpreter and its
    imports (coartic.cli, flask, sqlalchemy), which the tests' process has already loaded."""

    def __init__(self, study: Path, db: str) -> None:
        import threading

        from werkzeug.serving import make_server

        from coartic.perceive.server import create_app, load_study
        from coartic.perceive.storage import Store

        manifest, secret = load_study(study)
        self.store = Store(db, manifest, secret)
        self.server = make_server("127.0.0.1", 0, create_app(study, self.store), threaded=True)
        self.port = int(self.server.port)
        self.url = f"http://127.0.0.1:{self.port}/"  # as serve() prints it
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)
        self.thread.start()

    def stop(self) -> None:
        self.server.shutdown()
        self.server.server_close()
        self.thread.join(timeout=30)
        self.store.close()


def chromium_driver() -> Any:
    """A headless Chromium under Selenium, or a skip saying what to install."""
    pytest.importorskip("selenium")
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    browser = shutil.which("chromium")
    driver = shutil.which("chromedriver")
    if browser is None or driver is None:
        pytest.skip("needs Debian's chromium and chromium-driver (scripts/setup.sh installs them)")
    opts = webdriver.ChromeOptions()
    opts.binary_location = browser
    for a in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--mute-audio",
              "--window-size=900,700", "--no-first-run"):
        opts.add_argument(a)
    return webdriver.Chrome(options=opts, service=Service(driver))


# Selenium polls a wait's condition every half second by default: each trial waits for the answers'
# opening and the next page (the videos' ends are awaited in the page: play_all), so a participant's
# dozen trials idled seconds of wall time between events that had happened. Each poll is one round
# trip to chromedriver.
POLL = 0.05
# The trials' videos play at this rate: the page opens the answers on each video's `ended` event,
# which a faster playback fires too, at its end; how long a video lasts is the
# stimuli's business (test_perceive_face.py), not the server's. Chromium allows up to 16.
PLAYBACK_RATE = 8.0


def waiting(driver: Any, timeout: float = 20.0) -> Any:
    """A WebDriverWait that looks every POLL seconds."""
    from selenium.webdriver.support.ui import WebDriverWait

    return WebDriverWait(driver, timeout, poll_frequency=POLL)


def answer_current_trial(driver: Any, pick: Any, timeout: float = 20.0) -> tuple[int, int]:
    """Play every video of the trial page, wait until the answers open, answer with `pick(choices,
    instruction)` (a button's text). Returns (position counted from 1, total) read from the page."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support import expected_conditions as ec

    wait = waiting(driver, timeout)
    progress = wait.until(ec.presence_of_element_located((By.ID, "progress"))).text
    position, total = (int(x) for x in progress.split("/"))
    play_all(driver, timeout)
    wait.until(lambda d: all(b.is_enabled() for b in d.find_elements(By.CSS_SELECTOR, ".answer")))
    buttons = driver.find_elements(By.CSS_SELECTOR, "button.choice")
    instruction = driver.find_elements(By.ID, "instruction")
    text = pick([b.text for b in buttons], instruction[0].text if instruction else None)
    old = driver.find_element(By.ID, "answer-form")
    next(b for b in buttons if b.text == text).click()
    wait.until(ec.staleness_of(old))
    return position, total


def play_all(driver: Any, timeout: float = 20.0) -> int:
    """Play each video of the page to its end, one after the other, as a participant does (starting
    one pauses the others), at PLAYBACK_RATE. Returns how many there were. Each end is awaited in
    the page (a listener on the video's `ended`, set before the click), not polled for."""
    from selenium.webdriver.common.by import By

    buttons = driver.find_elements(By.CSS_SELECTOR, "button.play")
    driver.set_script_timeout(timeout)
    for button in buttons:
        video = button.find_element(By.XPATH, "preceding-sibling::video[1]")
        driver.execute_script("const v = arguments[0]; v.defaultPlaybackRate = v.playbackRate = arguments[1];"
                              "window.videoEnded = new Promise(done => v.addEventListener('ended', done, {once: true}));",
                              video, PLAYBACK_RATE)
        button.click()
        driver.execute_async_script("window.videoEnded.then(() => arguments[0]());")
    return len(buttons)


def wait_for_text(driver: Any, element_id: str, timeout: float = 20.0) -> str:
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support import expected_conditions as ec

    return str(waiting(driver, timeout).until(ec.presence_of_element_located((By.ID, element_id))).text)


def until(predicate: Any, timeout: float = 20.0) -> None:
    end = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > end:
            raise AssertionError("condition not met in time")
        time.sleep(0.05)
