"""`coartic perceive`, end to end in a real browser: a study prepared with Festival and the face,
served by the real server process, answered by simulated participants in headless Chromium
(Selenium); the server killed (SIGKILL) mid-session and restarted, the participant resuming; the
database holding every answer exactly once. The other designs' pages are served by the same app
from the tests' process (perceive_helpers.AppServer)."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path
from typing import Any

import pandas as pd
import pytest
from typer.testing import CliRunner

from coartic.cli import app

from perceive_helpers import AppServer, Server, answer_current_trial, chromium_driver, play_all, wait_for_text, waiting, write_spec

pytestmark = [pytest.mark.festival, pytest.mark.slow]


@pytest.fixture(scope="module")
def study(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from coartic.perceive.spec import read_study
    from coartic.perceive.stimuli import prepare_stimuli

    root = tmp_path_factory.mktemp("perceive")
    out = root / "study"
    prepare_stimuli(read_study(write_spec(root)), out)
    return out


@pytest.fixture(scope="module")
def browser() -> Any:
    """One headless Chromium for the file's tests: each start of one costs about a CPU-second."""
    d = chromium_driver()
    yield d
    d.quit()


@pytest.fixture()
def driver(browser: Any) -> Any:
    """The file's Chromium without the cookies of an earlier test: each test's participants are new."""
    browser.execute_cdp_cmd("Network.clearBrowserCookies", {})
    return browser


def rows(db: Path) -> list[tuple[Any, ...]]:
    with sqlite3.connect(db) as conn:
        return conn.execute("SELECT p.number, a.trial, a.kind, a.response, a.expected, a.correct "
                            "FROM answers a JOIN participants p ON p.id = a.participant_id "
                            "ORDER BY p.number, a.trial").fetchall()


def right_answer(choices: list[str], instruction: str | None) -> str:
    if instruction:  # the attention check names the button: «x»
        return instruction.split("«", 1)[1].split("»", 1)[0]
    return choices[0]


def consent(driver: Any, url: str) -> None:
    from selenium.webdriver.common.by import By

    driver.get(url)
    page = driver.page_source
    # the spec's text is shown as text, never run
    assert "&lt;script&gt;alert(1)&lt;/script&gt;" in page and "<script>alert" not in page
    assert "Tiny &lt;VCV&gt; study" in page
    driver.find_element(By.ID, "start").click()  # without agreeing: refused
    assert "agree" in wait_for_text(driver, "error")
    driver.find_element(By.ID, "agree").click()
    driver.find_element(By.ID, "start").click()


def test_participants_answer_in_chromium_and_resume_after_the_server_is_killed(study: Path, tmp_path: Path,
                                                                                  driver: Any) -> None:
    db = tmp_path / "results.sqlite"
    server = Server(study, f"sqlite:///{db}")
    assert server.url.startswith("http://127.0.0.1:")  # this machine only, unless --host says otherwise
    try:
        # participant 0 answers the whole study
        consent(driver, server.url)
        seen = []
        while True:
            position, total = answer_current_trial(driver, right_answer)
            seen.append(position)
            if position == total:
                break
        assert wait_for_text(driver, "completion-code") == "DONE-42"
        assert seen == list(range(1, total + 1))
        first = rows(db)
        assert [r[1] for r in first] == list(range(total)) and {r[0] for r in first} == {0}
        attention = [r for r in first if r[2] == "attention"]
        assert attention and all(r[5] == 1.0 for r in attention)  # instructed answers given: checks passed

        # participant 1 (another browser profile) answers two trials, then the server dies
        driver.delete_all_cookies()
        consent(driver, server.url)
        answer_current_trial(driver, right_answer)
        answer_current_trial(driver, right_answer)
        resume_url = driver.current_url
        assert "/p/" in resume_url
        before = rows(db)
        server.kill()
        assert rows(db) == before  # nothing acknowledged was lost
        server = Server(study, f"sqlite:///{db}", port=server.port)
        driver.get(resume_url)  # the participant reloads: they continue at trial 3
        position, total = answer_current_trial(driver, right_answer)
        assert position == 3
        # going back to an answered trial and answering it again stores nothing new
        driver.back()
        driver.back()
        driver.refresh()
        assert wait_for_text(driver, "progress").startswith("4 /")  # the page shows the first unanswered trial
        driver.execute_script(
            "const f = document.createElement('form'); f.method = 'post'; f.action = 'answer';"
            "for (const [k, v] of [['trial', '0'], ['choice', 'v']]) { const i = document.createElement('input');"
            "i.name = k; i.value = v; f.appendChild(i); } document.body.appendChild(f); f.submit();")
        wait_for_text(driver, "progress")
        while True:
            position, total = answer_current_trial(driver, right_answer)
            if position == total:
                break
        wait_for_text(driver, "done")
        # a participant coming back with a cookie is sent on to where they are (here: finished)
        driver.get(server.url)
        wait_for_text(driver, "done")
    finally:
        server.stop()
    final = rows(db)
    second = [r for r in final if r[0] == 1]
    assert [r[1] for r in second] == list(range(total))  # every trial exactly once
    assert second[:2] == [r for r in before if r[0] == 1]  # the answers before the crash, unchanged
    with sqlite3.connect(db) as conn:
        assert conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
        dup = conn.execute("SELECT participant_id, trial, COUNT(*) FROM answers GROUP BY 1, 2 HAVING COUNT(*) > 1")
        assert dup.fetchall() == []
        assert conn.execute("SELECT COUNT(*) FROM participants WHERE completed_at IS NOT NULL").fetchone()[0] == 2
    # simulated participants beside the two real ones, then the analysis of all of them
    runner = CliRunner()
    res = runner.invoke(app, ["perceive", "simulate", str(study), "--db", f"sqlite:///{db}", "-n", "6",
                              "--effect", "keyframe=-1"])
    assert res.exit_code == 0, res.output
    res = runner.invoke(app, ["perceive", "analyse", str(study), "--db", f"sqlite:///{db}", "--out",
                              str(tmp_path / "report")])
    assert res.exit_code == 0, res.output
    answers = pd.read_csv(tmp_path / "report" / "answers.csv")
    real = answers[answers["simulated"] == 0]
    assert sorted(real["participant"].unique()) == ["P0001", "P0002"] and len(real) == 2 * total
    assert answers["participant"].nunique() == 8
    assert "vcv-tiny" in (tmp_path / "report" / "report.html").read_text()


def other_design(study: Path, where: Path, design: str) -> Path:
    """A study of `design` whose two conditions x two items reuse the tiny study's videos (the pages
    and the answers are under test here, not the rendering)."""
    import shutil
    import tomllib

    from coartic.perceive.spec import parse_study
    from coartic.perceive.stimuli import manifest_of

    conds = '[[condition]]\nname = "coarticulation"\nreference = true\n[[condition]]\nname = "keyframe"\nface = "step"\n' \
        if design == "mushra" else '[[condition]]\nname = "coarticulation"\n[[condition]]\nname = "keyframe"\nface = "step"\n'
    typed = design == "text"
    typed_keys = 'response = "text"\nsnr_db = [0.0]' if typed else ""
    text = (f'[study]\nname = "{design}-tiny"\ndesign = "{"intelligibility" if typed else design}"\nseed = 5\n'
            f'consent = "ok"\nattention_every = 0\ncounterbalance = "{"latin" if typed else "full"}"\n'
            f'[stimuli]\nitems = ["aba", "ava"]\n{typed_keys}\n{conds}')
    spec = parse_study(tomllib.loads(text), where / "s.toml")
    old = json.loads((study / "study.json").read_text())
    stimuli = old["stimuli"] if typed else [{**s, "snr_db": None} for s in old["stimuli"]]
    out = where / design
    shutil.copytree(study / "stimuli", out / "stimuli")
    (out / "study.json").write_text(json.dumps(manifest_of(spec, stimuli)))
    (out / "secret.key").write_text("k\n")
    return out


@pytest.mark.parametrize("design", ["preference", "mushra", "text"])
def test_preference_mushra_and_typed_answers_in_chromium(study: Path, tmp_path: Path, driver: Any, design: str) -> None:
    from selenium.webdriver.common.by import By

    other = other_design(study, tmp_path, design)
    db = tmp_path / "r.sqlite"
    server = AppServer(other, f"sqlite:///{db}")  # the pages under test; the process is the test above's
    try:
        driver.get(server.url)
        driver.find_element(By.ID, "agree").click()
        driver.find_element(By.ID, "start").click()
        for k in range(2):  # two items, one trial each
            assert wait_for_text(driver, "progress") == f"{k + 1} / 2"
            assert play_all(driver) == {"mushra": 3, "preference": 2, "text": 1}[design]  # MUSHRA: the reference too
            waiting(driver).until(
                lambda d: all(e.is_enabled() for e in d.find_elements(By.CSS_SELECTOR, ".answer")))
            old = driver.find_element(By.ID, "answer-form")
            if design == "preference":
                driver.find_element(By.ID, "choice-1").click()  # "Face B"
            elif design == "text":
                driver.find_element(By.ID, "text").send_keys("<b>Aba</b> ava")
                driver.find_element(By.ID, "submit").click()
            else:
                driver.execute_script("document.getElementById('rating-0').value = 91;"
                                      "document.getElementById('rating-1').value = 17;")
                driver.find_element(By.ID, "submit").click()
            waiting(driver).until(lambda d: old not in d.find_elements(By.ID, "answer-form"))
        wait_for_text(driver, "done")
    finally:
        server.stop()
    with sqlite3.connect(db) as conn:
        got = conn.execute("SELECT trial, conditions, response, correct FROM answers ORDER BY trial").fetchall()
    assert [g[0] for g in got] == [0, 1]
    for _, conditions, response, correct in got:
        shown = json.loads(conditions)
        if design == "text":  # stored as typed; scored by the item's words ("aba" or "ava": one of them typed)
            assert json.loads(response) == "<b>Aba</b> ava" and correct == 1.0
        elif design == "preference":
            assert json.loads(response) == shown[1]  # the face shown second, by condition name
        else:
            assert json.loads(response) == {shown[0]: 91, shown[1]: 17}
