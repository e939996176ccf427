"""coartic.perceive without a browser: the study spec, each participant's trials, the noise at its SNR,
the keyframe face, and the database's one-answer-per-trial rule (real SQLite files)."""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from coartic.errors import SpecError
from coartic.io.labels import Segments
from coartic.perceive.design import participant_trials, score, stimulus_trials
from coartic.perceive.spec import parse_study, read_study
from coartic.perceive.stimuli import make_noise, manifest_of, mix_at_snr, step_animation
from coartic.perceive.storage import StorageError, Store
from coartic.runtime.animate import animate
from coartic.runtime.shipped import load_shipped_table
from perceive_helpers import TINY_STUDY, write_spec


def fake_manifest(design: str = "intelligibility", counterbalance: str = "full", attention_every: int = 3,
                  conditions: int = 2, items: int = 4, snrs: tuple[float | None, ...] = (-6.0, 0.0)) -> dict[str, Any]:
    """A study.json as prepare writes it, without rendering (the stimuli's files are never read here)."""
    cond_toml = "".join(f'[[condition]]\nname = "c{k}"\n' + ('reference = true\n' if design == "mushra" and k == 0 else "")
                        + (f'answer = "e{k}"\n' if design == "emotion" else "") for k in range(conditions))
    vowels = "aeiou"
    item_list = ", ".join(f'"{vowels[k % 5]}{c}{vowels[k % 5]}"' for k, c in zip(range(items), "bdgvmnlr"))
    snr = "" if snrs == (None,) else "snr_db = [" + ", ".join(str(s) for s in snrs) + "]\n"
    text = (f'[study]\nname = "t"\ndesign = "{design}"\nseed = 3\nconsent = "ok"\nattention_every = {attention_every}\n'
            f'counterbalance = "{counterbalance}"\n[stimuli]\nitems = [{item_list}]\n{snr}{cond_toml}')
    import tomllib

    spec = parse_study(tomllib.loads(text), Path("t.toml"))
    stimuli = []
    for i in range(items):
        for c in spec.conditions:
            for s in spec.snr_db:
                stimuli.append({"id": f"s{len(stimuli) + 1:04d}", "item": i, "condition": c.name, "snr_db": s,
                                "file": f"stimuli/s{len(stimuli) + 1:04d}.mp4"})
    return manifest_of(spec, stimuli)


# ---------------------------------------------------------------------------------- spec
def test_the_tiny_study_reads(tmp_path: Path) -> None:
    spec = read_study(write_spec(tmp_path))
    assert spec.design == "intelligibility" and spec.answers == ("b", "v") and spec.n_stimuli() == 4
    assert [c.face for c in spec.conditions] == ["model", "step"]


@pytest.mark.parametrize(("change", "key", "words"), [
    (('design = "intelligibility"', 'design = "quiz"'), "study.design", "must be one of"),
    (("snr_db = [0.0]\n", ""), "stimuli.snr_db", "is required for intelligibility"),
    (('items = ["aba", "ava"]', 'items = ["aba", "casa"]'), "stimuli.answers", "'casa' is not a VCV"),
    (('face = "step"', 'face = "cartoon"'), "condition #2.face", "must be one of model, step, still"),
    (('name = "keyframe"', 'name = "coarticulation"'), "condition #2.name", "names condition #1 already"),
    (("seed = 7\n", ""), "study.seed", "is required"),
    (("fps = 10", "fps = 10\nframes = 3"), "stimuli.frames", "unknown key"),
])
def test_spec_errors_name_the_file_and_key(tmp_path: Path, change: tuple[str, str], key: str, words: str) -> None:
    path = write_spec(tmp_path, TINY_STUDY.replace(*change))
    with pytest.raises(SpecError) as err:
        read_study(path)
    assert err.value.key == key and words in str(err.value) and str(path) in str(err.value)


def test_a_missing_table_file_is_named(tmp_path: Path) -> None:
    path = write_spec(tmp_path, TINY_STUDY.replace('face = "step"', 'table = "nope.json"'))
    with pytest.raises(SpecError, match=r"\[condition #2.table\] no such table file .*nope.json"):
        read_study(path)


# ---------------------------------------------------------------------------------- design
def test_trials_are_reproducible_and_shuffled_per_participant() -> None:
    m = fake_manifest()
    a, b = participant_trials(m, 0), participant_trials(m, 1)
    assert participant_trials(m, 0) == a
    assert [t["stimuli"] for t in a] != [t["stimuli"] for t in b]
    stim = [t for t in a if t["kind"] == "stimulus"]
    assert sorted(s for t in stim for s in t["stimuli"]) == [s["id"] for s in m["stimuli"]]  # each exactly once
    # an attention check after every 3 stimulus trials, asking for one of the answer buttons
    kinds = [t["kind"] for t in a]
    assert kinds[:8] == ["stimulus"] * 3 + ["attention"] + ["stimulus"] * 3 + ["attention"]
    assert all(t["answer"] in m["choices"] for t in a if t["kind"] == "attention")


def test_latin_square_shows_each_item_once_per_snr_and_balances_conditions() -> None:
    m = fake_manifest(counterbalance="latin", conditions=2, items=4)
    seen: dict[tuple[int, float], set[str]] = {}
    for number in range(2):
        trials = stimulus_trials(m, number)
        assert len(trials) == 4 * 2  # items x SNRs
        for t in trials:
            seen.setdefault((t["item"], t["snr_db"]), set()).update(t["conditions"])
    assert all(v == {"c0", "c1"} for v in seen.values())  # over two participants, every item in both conditions


def test_preference_positions_are_counterbalanced() -> None:
    m = fake_manifest(design="preference", conditions=3, items=2, snrs=(None,))
    firsts = [t["conditions"][0] for n in range(2) for t in stimulus_trials(m, n)]
    pairs = [tuple(sorted(t["conditions"])) for t in stimulus_trials(m, 0)]
    assert len(pairs) == 2 * 3 and len(set(pairs)) == 3  # every pair of conditions, per item
    for pair in set(pairs):  # each condition of a pair is shown first equally often over participants 0 and 1
        shown = [f for n in range(2) for t in stimulus_trials(m, n) if tuple(sorted(t["conditions"])) == pair
                 for f in [t["conditions"][0]]]
        assert shown.count(pair[0]) == shown.count(pair[1])
    assert set(firsts) == {"c0", "c1", "c2"}


def test_scores() -> None:
    m = fake_manifest()
    t = {"kind": "stimulus", "answer": "b"}
    assert score(m, t, "b") == 1.0 and score(m, t, "d") == 0.0
    text = {**m, "response": "text"}
    assert score(text, {"kind": "stimulus", "answer": "Perché no, Anna?"}, "perche NO") == pytest.approx(2 / 3)


# ---------------------------------------------------------------------------------- stimuli
@pytest.mark.parametrize("kind", ["white", "speech-shaped"])
@pytest.mark.parametrize("snr", [-6.0, 0.0, 10.0])
def test_noise_is_mixed_at_the_stated_snr(kind: str, snr: float) -> None:
    rng = np.random.default_rng(1)
    rate, n = 16000, 16000
    t = np.arange(n) / rate
    speech = 0.3 * np.sin(2 * np.pi * 220 * t) * (t > 0.2) * (t < 0.8)
    mask = (t > 0.2) & (t < 0.8)
    f = np.linspace(0, rate / 2, 257)
    spectrum = (f, 1.0 / (1.0 + (f / 500.0) ** 2))
    noise = make_noise(n, rate, kind, spectrum, rng)
    mixed, measured = mix_at_snr(speech, mask, noise, snr)
    assert measured == pytest.approx(snr, abs=0.05)
    assert np.max(np.abs(mixed)) <= 0.98 + 1e-12
    # the speech's level is the same at every SNR unless the mixture had to be scaled down to fit
    clean, none = mix_at_snr(speech, mask, None, None)
    assert none is None and np.sqrt(np.mean(clean[mask] ** 2)) == pytest.approx(10 ** (-26 / 20), rel=1e-9)


def test_the_keyframe_face_holds_each_target_over_its_segment() -> None:
    table = load_shipped_table()
    seg = Segments(("#", "a", "p", "a", "#"), np.array([0.0, 0.1, 0.3, 0.4, 0.6]), np.array([0.1, 0.3, 0.4, 0.6, 0.8]))
    model = animate(table, seg, 100.0)
    step = step_animation(model, table)
    k = np.searchsorted(model.times, 0.35)
    for c in model.modelled:
        assert step.channels[c][k] == table.values["p"][c]["target"]
        assert step.channels[c][5] == table.values["#"][c]["target"]
        assert len(np.unique(step.channels[c])) <= 3  # piecewise constant: one value per phoneme
    # the coarticulated face moves between the targets; the keyframe face jumps
    assert np.max(np.abs(np.diff(step.channels["LLO"]))) > np.max(np.abs(np.diff(model.channels["LLO"])))


# ---------------------------------------------------------------------------------- storage
def test_each_answer_is_stored_once_and_survives_reopening(tmp_path: Path) -> None:
    m = fake_manifest()
    url = f"sqlite:///{tmp_path / 'r.sqlite'}"
    store = Store(url, m, "key")
    p = store.start()
    assert store.next_trial(p) == 0
    assert store.record(p, 0, "b") is True
    assert store.record(p, 0, "d") is False  # a resubmission: the first answer stands
    # the same answer from many threads at once: stored once
    results: list[bool] = []
    threads = [threading.Thread(target=lambda: results.append(store.record(p, 1, "b"))) for _ in range(8)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    assert results.count(True) == 1
    store.close()
    again = Store(url, m, "key")
    rows = again.answer_rows()
    assert [(r["trial"], r["response"]) for r in rows] == [(0, '"b"'), (1, '"b"')]
    assert again.next_trial(again.by_token(p.token) or p) == 2
    # a panel identifier is stored as a keyed hash, and brings the participant back
    q = again.start("PANEL-123")
    assert again.start("PANEL-123").token == q.token and q.number == 1
    raw = (tmp_path / "r.sqlite").read_bytes() + (tmp_path / "r.sqlite-wal").read_bytes() \
        if (tmp_path / "r.sqlite-wal").exists() else (tmp_path / "r.sqlite").read_bytes()
    assert b"PANEL-123" not in raw
    again.close()


def test_a_database_of_another_study_is_refused(tmp_path: Path) -> None:
    url = f"sqlite:///{tmp_path / 'r.sqlite'}"
    Store(url, fake_manifest(), "k").close()
    with pytest.raises(StorageError, match="holds the results of study 't' as prepared another time"):
        Store(url, fake_manifest(items=3), "k")


def test_an_emotion_condition_speaks_with_the_table_blended_as_speak_does(tmp_path: Path) -> None:
    from coartic.emotions import EmotionError, emotion_table
    from coartic.perceive.spec import Condition
    from coartic.perceive.stimuli import condition_table
    from coartic.synthetic_cli import load_generator
    from coartic.table import ParameterTable

    root = Path(__file__).resolve().parents[2]
    gen = load_generator()
    truth = gen.emotive_truth(ParameterTable.load(root / "corpus-synthetic" / "ground_truth.json"), gen.load_emotions())
    path = tmp_path / "emotive.json"
    truth.save(path)
    joy = condition_table(Condition(name="joy", table=path, emotion="joy", intensity=0.6))
    assert joy.values == emotion_table(ParameterTable.load(path), "joy", 0.6).values
    assert joy.values != ParameterTable.load(path).values  # the emotion moved some targets
    assert condition_table(Condition(name="n", table=path)).values == ParameterTable.load(path).values
    with pytest.raises(EmotionError, match="fitted without emotions"):
        condition_table(Condition(name="joy", emotion="joy"))  # the shipped table has none
    # an emotion study asks for the conditions' emotions
    m = manifest_of(parse_study({"study": {"name": "e", "design": "emotion", "seed": 1, "consent": "ok"},
                                 "stimuli": {"items": ["apa"]},
                                 "condition": [{"name": "j", "table": str(path), "emotion": "joy"},
                                               {"name": "s", "table": str(path), "emotion": "sadness"}]},
                                Path("e.toml")), [])
    assert m["choices"] == ["joy", "sadness"]


def test_prepare_refuses_a_directory_holding_answers(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from coartic.cli import app

    out = tmp_path / "study"
    out.mkdir()
    (out / "results.sqlite").write_bytes(b"")
    res = CliRunner().invoke(app, ["perceive", "prepare", str(write_spec(tmp_path)), "--out", str(out), "--force"])
    assert res.exit_code == 2 and "holds a results database" in res.output
    assert sorted(p.name for p in out.iterdir()) == ["results.sqlite"]
