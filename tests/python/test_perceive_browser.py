"""`coartic perceive`, end to end in a real browser: a study prepared with Festival and the face,
served by the real server process, answered by simulated participants in headless Chromium
(Selenium); the server killed (SIGKILL) mid-session and restarted, the participant resuming; the
database holding every answer exactly once."""

from __future__ import annotations

import sqlite3
from pathlib import Path
from typing import Any

import pytest

from perceive_helpers import Server, answer_current_trial, chromium_driver, wait_for_text, write_spec

pytestmark = [pytest.mark.festival, pytest.mark.slow]


@pytest.fixture(scope="module")
def study(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from coartic.perceive.spec import read_study
    from coartic.perceive.stimuli import prepare_stimuli

    root = tmp_path_factory.mktemp("perceive")
    out = root / "study"
    prepare_stimuli(read_study(write_spec(root)), out)
    return out


@pytest.fixture()
def driver() -> Any:
    d = chromium_driver()
    yield d
    d.quit()


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
