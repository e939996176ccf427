"""coartic perceive on a real PostgreSQL server (Debian's postgresql, a throwaway cluster on a Unix
socket in a temporary directory): one answer per trial under concurrent submissions, resuming, the
study fingerprint, and the server process answering through it."""

from __future__ import annotations

import glob
import os
import shutil
import subprocess
import tempfile
import threading
import urllib.parse
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import pytest

from perceive_helpers import Server
from test_perceive_study import fake_manifest


def _pg_bin(name: str) -> str | None:
    found = shutil.which(name)
    if found:
        return found
    versions = sorted(glob.glob(f"/usr/lib/postgresql/*/bin/{name}"))
    return versions[-1] if versions else None


@pytest.fixture(scope="module")
def pg_url() -> Iterator[str]:
    initdb, pg_ctl = _pg_bin("initdb"), _pg_bin("pg_ctl")
    if initdb is None or pg_ctl is None:
        pytest.skip("needs PostgreSQL's initdb and pg_ctl (Debian package postgresql; scripts/setup.sh)")
    # not under pytest's temporary directory, which only root may enter; a short path for the socket
    root = Path(tempfile.mkdtemp(prefix="coartic-pg-"))
    data, sock = root / "data", root / "sock"
    sock.mkdir()
    prefix: list[str] = []
    if os.geteuid() == 0:  # initdb refuses to run as root: run the cluster as the postgres user
        if shutil.which("runuser") is None:
            pytest.skip("running as root without runuser: cannot start PostgreSQL as another user")
        shutil.chown(root, "postgres")
        shutil.chown(sock, "postgres")
        prefix = ["runuser", "-u", "postgres", "--"]
    # --no-sync: initdb would sync its thousand files to disk, 8 of its 9.5 s wall here, for a cluster
    # thrown away after the module (the server itself runs with fsync=on, as in a study)
    subprocess.run([*prefix, initdb, "--no-sync", "-D", str(data), "-U", "postgres", "--auth=trust", "-E", "UTF8"],
                   check=True, capture_output=True, timeout=120)
    subprocess.run([*prefix, pg_ctl, "-D", str(data), "-w", "-t", "60", "-l", str(root / "log"), "-o",
                    f"-k {sock} -c listen_addresses='' -c fsync=on", "start"], check=True, capture_output=True,
                   timeout=120)
    try:
        yield f"postgresql://postgres@/postgres?host={sock}"
    finally:
        subprocess.run([*prefix, pg_ctl, "-D", str(data), "-m", "immediate", "stop"], capture_output=True, timeout=60)
        shutil.rmtree(root, ignore_errors=True)


def test_answers_once_each_on_postgresql(pg_url: str) -> None:
    from coartic.perceive.storage import StorageError, Store

    m = fake_manifest()
    store = Store(pg_url, m, "key")
    p = store.start("PANEL-9")
    results: list[bool] = []
    threads = [threading.Thread(target=lambda: results.append(store.record(p, 0, "b"))) for _ in range(8)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    assert results.count(True) == 1
    assert store.record(p, 1, "d") is True and store.record(p, 1, "b") is False
    store.close()
    again = Store(pg_url, m, "key")
    assert again.start("PANEL-9").token == p.token  # the panel id brings the participant back
    assert [(r["trial"], r["response"]) for r in again.answer_rows()] == [(0, '"b"'), (1, '"d"')]
    assert again.next_trial(p) == 2
    again.close()
    with pytest.raises(StorageError, match="as prepared another time"):
        Store(pg_url, fake_manifest(items=3), "key")


def test_the_server_stores_through_postgresql(pg_url: str, tmp_path: Path) -> None:
    from coartic.perceive.storage import Store, answers, metadata, participants

    m = fake_manifest()
    m["name"] = "served"
    # a fresh schema for this study: the module's other test holds another study's results
    store = Store(pg_url, fake_manifest(), "key")
    with store.engine.begin() as conn:
        conn.execute(answers.delete())
        conn.execute(participants.delete())
        metadata.tables["meta"].drop(conn)
    store.close()
    study = tmp_path / "study"
    (study / "stimuli").mkdir(parents=True)
    import json

    (study / "study.json").write_text(json.dumps(m))
    (study / "secret.key").write_text("k\n")
    server = Server(study, pg_url)
    try:
        opener = urllib.request.build_opener(urllib.request.HTTPCookieProcessor())
        page = opener.open(server.url + "start", data=urllib.parse.urlencode({"agree": "yes"}).encode())
        trial_url = page.geturl()
        assert "/p/" in trial_url and "1 / " in page.read().decode()
        for _ in range(2):  # the same answer posted twice (a double click): stored once
            opener.open(trial_url + "answer", data=urllib.parse.urlencode({"trial": "0", "choice": "b"}).encode())
        assert "2 / " in opener.open(trial_url).read().decode()
    finally:
        server.stop()
    store = Store(pg_url, m, "k")
    rows = store.answer_rows()
    store.close()
    assert [(r["trial"], r["response"]) for r in rows] == [(0, '"b"')]
