"""The fitting library returns results and writes nothing; the fit job writes them (issue 28 item 2).

``coartic.fit.runner.run`` tells its caller after every channel (``on_channel``), which is how the
job (``coartic.jobs.fit.fit_job``) keeps what an interrupted run finished; a ``[choose]`` setting is
chosen by the chooser it is given (cross-validation is an evaluation, above the fit)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from coartic.errors import UsageError
from coartic.evaluation.choose import Choice, cross_validate
from coartic.fit.result import FitResult
from coartic.fit.runner import run
from coartic.fit.simulate import vcv_utterances
from coartic.fit.spec import FitSpec, parse_spec
from coartic.jobs.fit import fit_job
from coartic.model import Utterance


def spec_of(tmp: Path, **more: object) -> FitSpec:
    raw: dict[str, object] = {"corpus": {"files": ["x"], "labels": ["y"]}, "model": {"channels": ["LLO", "ULO"]},
                              "parameters": {"free": ["target"]}, "staging": {"enabled": False}, **more}
    return parse_spec(raw, tmp / "spec.toml")


@pytest.fixture(scope="module")
def utts() -> list[Utterance]:
    made = vcv_utterances(np.random.default_rng(3), repetitions=2, rates={"normal": 1.0}, noise=0.1)
    for u in made:  # a second channel: the first one moved, so that there are two to report
        u.observed["ULO"] = u.observed["LLO"] + 2.0
        u.valid["ULO"] = u.valid["LLO"].copy()
    return made


def test_the_library_writes_nothing_and_reports_every_channel(tmp_path: Path, utts: list[Utterance],
                                                             monkeypatch: pytest.MonkeyPatch) -> None:
    seen: list[list[str]] = []
    monkeypatch.chdir(tmp_path)  # anything written relative to the working directory would land here

    def done(result: FitResult) -> None:
        seen.append(list(result.channels))

    res = run(spec_of(tmp_path), utterances=utts, quiet=True, on_channel=done)
    assert seen == [["LLO"], ["LLO", "ULO"]]  # after each channel, with what is finished so far
    assert list(res.channels) == ["LLO", "ULO"] and res.validation is None and res.report is None
    assert sorted(p.name for p in tmp_path.rglob("*")) == []
    assert res.utterances and all(u.name for u in res.utterances)  # what a validation splits


def test_the_job_saves_after_every_channel(tmp_path: Path, utts: list[Utterance],
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    saved: list[list[str]] = []
    real = FitResult.save

    def save(self: FitResult, out: str | Path) -> dict[str, Path]:
        saved.append(list(self.channels))
        return real(self, out)

    monkeypatch.setattr(FitResult, "save", save)
    res = fit_job(spec_of(tmp_path), tmp_path / "out", utterances=utts, quiet=True, report=False)
    assert saved == [["LLO"], ["LLO", "ULO"], ["LLO", "ULO"]]  # each channel, then the whole (validation)
    assert (tmp_path / "out" / "table.json").is_file() and res.report is None


def test_a_choice_needs_the_chooser_the_job_passes(tmp_path: Path, utts: list[Utterance]) -> None:
    s = spec_of(tmp_path, model={"channels": ["LLO"], "dominance": "plateau", "plateau_fraction": 0.5},
                choose={"key": "plateau_fraction", "values": [0.0, 1.0], "group": "repetition", "folds": 2,
                        "rule": "min"})
    with pytest.raises(UsageError, match=r"\[choose\] plateau_fraction is chosen by cross-validation.*fit_job"):
        run(s, utterances=utts, quiet=True)
    lib = run(s, utterances=utts, quiet=True, choose=cross_validate)
    job = fit_job(s, utterances=utts, quiet=True, report=False)
    assert isinstance(lib.choice, Choice) and isinstance(job.choice, Choice)
    assert lib.choice.chosen == job.choice.chosen
    assert lib.table().values == job.table().values
