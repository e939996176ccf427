"""The results database (SQLAlchemy Core): SQLite by default, PostgreSQL by URL.

Three tables: `meta` (which study the database belongs to), `participants` (a number by arrival, a
random token that is their link, the keyed hash of a panel identifier if one was given, their
trials as assigned when they started) and `answers` (one row per participant and trial: the unique
key makes a repeated submission, a reload, a double click or a retry after a crash, a no-op).

Every answer is committed before the server acknowledges it. SQLite runs in write-ahead-log mode
with synchronous=FULL, so a committed answer survives the server being killed (and the machine
losing power); PostgreSQL commits durably by default.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import secrets
from dataclasses import dataclass
from datetime import datetime, timezone
from typing import Any

from sqlalchemy import (Column, Float, ForeignKey, Integer, MetaData, String, Table, Text, UniqueConstraint,
                        bindparam, create_engine, event, func, insert, select, update)
from sqlalchemy.engine import Engine
from sqlalchemy.exc import IntegrityError, SQLAlchemyError

from coartic.errors import CoarticError
from coartic.perceive.design import participant_trials, score

SCHEMA_VERSION = "1"

metadata = MetaData()
meta_table = Table("meta", metadata, Column("key", String(64), primary_key=True), Column("value", Text, nullable=False))
participants = Table(
    "participants", metadata,
    Column("id", Integer, primary_key=True, autoincrement=True),
    Column("number", Integer, nullable=False, unique=True),
    Column("token", String(64), nullable=False, unique=True),
    Column("external", String(64), unique=True),
    Column("created_at", String(40), nullable=False),
    Column("completed_at", String(40)),
    Column("trials", Text, nullable=False),
    Column("simulated", Integer, nullable=False, default=0),
)
answers = Table(
    "answers", metadata,
    Column("id", Integer, primary_key=True, autoincrement=True),
    Column("participant_id", Integer, ForeignKey("participants.id"), nullable=False),
    Column("trial", Integer, nullable=False),
    Column("kind", String(16), nullable=False),
    Column("item", Integer, nullable=False),
    Column("conditions", Text, nullable=False),
    Column("snr_db", Float),
    Column("stimuli", Text, nullable=False),
    Column("expected", Text),
    Column("response", Text, nullable=False),
    Column("correct", Float),
    Column("rt_ms", Integer),
    Column("answered_at", String(40), nullable=False),
    UniqueConstraint("participant_id", "trial", name="one_answer_per_trial"),
)


# record()'s statements, built once with their parameters bound at execution: built per answer, SQLAlchemy
# coerced every value and derived the statement's cache key each time, most of an answer's CPU
_ANSWER_OF = select(answers.c.id).where(answers.c.participant_id == bindparam("pid"), answers.c.trial == bindparam("trial"))
_INSERT_ANSWER = insert(answers)
# (participant_id, trial) is unique: the count is the number of trials answered
_ANSWERS_OF = select(func.count()).select_from(answers).where(answers.c.participant_id == bindparam("pid"))
_COMPLETE = (update(participants).where(participants.c.id == bindparam("pid"), participants.c.completed_at.is_(None))
             .values(completed_at=bindparam("at")))


class StorageError(CoarticError, RuntimeError):
    """The results database cannot be used (wrong study, unreachable server, bad URL)."""


@dataclass(frozen=True)
class Participant:
    id: int
    number: int
    token: str
    trials: list[dict[str, Any]]
    completed: bool


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="milliseconds")


def engine_for(url: str, durable: bool = True) -> Engine:
    """An engine for `url` (sqlite:///path or postgresql://...; the latter through psycopg 3).
    SQLite: `durable` syncs every commit to disk (synchronous=FULL); otherwise (simulated answers,
    which a crash may cost) the log is synced at checkpoints only (NORMAL: still atomic)."""
    if url.startswith("postgresql://") or url.startswith("postgres://"):
        url = "postgresql+psycopg://" + url.split("://", 1)[1]
    try:
        engine = create_engine(url, future=True)
    except (SQLAlchemyError, ImportError, ValueError) as err:
        raise StorageError(f"cannot open the results database {url!r}: {err} (use sqlite:///PATH or "
                           "postgresql://USER@HOST/DB; PostgreSQL needs the psycopg package)") from None
    if engine.dialect.name == "sqlite":
        @event.listens_for(engine, "connect")
        def _pragmas(dbapi_conn: Any, _record: Any) -> None:
            cur = dbapi_conn.cursor()
            cur.execute("PRAGMA journal_mode=WAL")
            cur.execute("PRAGMA synchronous=FULL" if durable else "PRAGMA synchronous=NORMAL")
            cur.execute("PRAGMA foreign_keys=ON")
            cur.execute("PRAGMA busy_timeout=10000")
            cur.close()
    return engine


def study_fingerprint(manifest: dict[str, Any]) -> str:
    """What ties a database to one prepared study: its name, design, seed and stimuli."""
    key = json.dumps([manifest["name"], manifest["design"], manifest["seed"], manifest["stimuli"]], sort_keys=True)
    return hashlib.sha256(key.encode()).hexdigest()


class Store:
    """The results of one study in one database."""

    def __init__(self, url: str, manifest: dict[str, Any], secret: str = "", durable: bool = True) -> None:
        self.url = url
        self.manifest = manifest
        self.secret = secret.encode()
        self.engine = engine_for(url, durable)
        fingerprint = study_fingerprint(manifest)
        try:
            metadata.create_all(self.engine)
            with self.engine.begin() as conn:
                have = {k: v for k, v in conn.execute(select(meta_table.c.key, meta_table.c.value))}
                if not have:
                    conn.execute(insert(meta_table), [{"key": "study", "value": manifest["name"]},
                                                      {"key": "fingerprint", "value": fingerprint},
                                                      {"key": "schema", "value": SCHEMA_VERSION}])
                elif have.get("fingerprint") != fingerprint:
                    raise StorageError(f"{safe_url(url)} holds the results of study {have.get('study')!r} as prepared "
                                       f"another time (other stimuli or seed), not of {manifest['name']!r} as prepared "
                                       "now: give another --db")
        except SQLAlchemyError as err:
            raise StorageError(f"cannot use the results database {safe_url(url)}: {err.__class__.__name__}: "
                               f"{str(err).splitlines()[0]}") from None

    def close(self) -> None:
        self.engine.dispose()

    # ------------------------------------------------------------------ participants
    def pseudonym(self, external: str) -> str:
        """The keyed hash stored for a panel identifier (the identifier itself is never stored)."""
        return hmac.new(self.secret, external.encode(), hashlib.sha256).hexdigest()

    def _row(self, row: Any) -> Participant:
        return Participant(id=row.id, number=row.number, token=row.token, trials=json.loads(row.trials),
                           completed=row.completed_at is not None)

    def by_token(self, token: str) -> Participant | None:
        with self.engine.connect() as conn:
            row = conn.execute(select(participants).where(participants.c.token == token)).first()
        return None if row is None else self._row(row)

    def start(self, external: str | None = None, simulated: bool = False) -> Participant:
        """A new participant (the next number, their trials), or the one who already started with
        this panel identifier."""
        pseud = None if external is None else self.pseudonym(external)
        for _ in range(20):
            with self.engine.begin() as conn:
                if pseud is not None:
                    row = conn.execute(select(participants).where(participants.c.external == pseud)).first()
                    if row is not None:
                        return self._row(row)
                number = int(conn.execute(select(func.coalesce(func.max(participants.c.number), -1))).scalar_one()) + 1
                trials = participant_trials(self.manifest, number)
                token = secrets.token_urlsafe(16)
                try:
                    with conn.begin_nested():
                        key = conn.execute(insert(participants).values(
                            number=number, token=token, external=pseud, created_at=_now(),
                            trials=json.dumps(trials), simulated=int(simulated))).inserted_primary_key
                        assert key is not None
                        pid = key[0]
                except IntegrityError:
                    continue  # another participant took the number (or the same panel id) meanwhile: again
                return Participant(id=int(pid), number=number, token=token, trials=trials, completed=False)
        raise StorageError("could not assign a participant number after 20 attempts (the database is very busy)")

    def answered(self, participant: Participant) -> set[int]:
        with self.engine.connect() as conn:
            return set(conn.execute(select(answers.c.trial).where(answers.c.participant_id == participant.id)).scalars())

    def next_trial(self, participant: Participant) -> int | None:
        """The first trial not answered yet (None: all answered)."""
        done = self.answered(participant)
        return next((k for k in range(len(participant.trials)) if k not in done), None)

    # ------------------------------------------------------------------ answers
    def record(self, participant: Participant, trial: int, response: Any, rt_ms: int | None = None) -> bool:
        """Store the answer to `trial` once: True if stored now, False if it was stored before
        (the first answer stands). Committed before returning."""
        t = participant.trials[trial]
        row = {"participant_id": participant.id, "trial": trial, "kind": t["kind"], "item": t["item"],
               "conditions": json.dumps(t["conditions"]), "snr_db": t["snr_db"], "stimuli": json.dumps(t["stimuli"]),
               "expected": t["answer"], "response": json.dumps(response, ensure_ascii=False),
               "correct": score(self.manifest, t, response), "rt_ms": rt_ms, "answered_at": _now()}
        try:
            with self.engine.begin() as conn:
                if conn.execute(_ANSWER_OF, {"pid": participant.id, "trial": trial}).first() is not None:
                    return False
                conn.execute(_INSERT_ANSWER, row)
                if conn.execute(_ANSWERS_OF, {"pid": participant.id}).scalar_one() == len(participant.trials):
                    conn.execute(_COMPLETE, {"pid": participant.id, "at": _now()})
        except IntegrityError:
            return False  # the same answer committed by a concurrent request
        return True

    # ------------------------------------------------------------------ reading back
    def answer_rows(self) -> list[dict[str, Any]]:
        """Every answer with its participant's number, in participant and trial order."""
        q = (select(answers, participants.c.number, participants.c.simulated)
             .join(participants, answers.c.participant_id == participants.c.id)
             .order_by(participants.c.number, answers.c.trial))
        with self.engine.connect() as conn:
            return [dict(r._mapping) for r in conn.execute(q)]

    def counts(self) -> dict[str, int]:
        with self.engine.connect() as conn:
            n_p = int(conn.execute(select(func.count()).select_from(participants)).scalar_one())
            n_done = int(conn.execute(select(func.count()).select_from(participants)
                                      .where(participants.c.completed_at.is_not(None))).scalar_one())
            n_a = int(conn.execute(select(func.count()).select_from(answers)).scalar_one())
        return {"participants": n_p, "completed": n_done, "answers": n_a}


def safe_url(url: str) -> str:
    """The URL without its password, for messages."""
    from sqlalchemy.engine import make_url

    try:
        return make_url(url).render_as_string(hide_password=True)
    except Exception:  # noqa: BLE001 - an unparsable URL is shown as given
        return url
