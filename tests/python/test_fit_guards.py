"""Small-data guards (issue 19 item 8): settings the data cannot support are refused or warned about
with the reason and the alternative; parameters the data cannot identify say why."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from coartic.fit import run
from coartic.jobs.fit import fit_job
from coartic.fit.guards import small_data_notes
from coartic.estimation.parameters import psd_pseudo_inverse
from coartic.fit.result import unidentified_reasons
from coartic.fit.simulate import vcv_utterances
from coartic.errors import SpecError
from coartic.fit.spec import parse_spec


def spec(tmp_path: Path, **sections: object):  # type: ignore[no-untyped-def]
    raw = {"corpus": {"files": ["x"], "labels": ["y"]}, "model": {"channels": ["LLO"]},
           "parameters": {"free": ["target"]}, "staging": {"enabled": False}, **sections}
    return parse_spec(raw, tmp_path / "spec.toml")


def utts(n: int):  # type: ignore[no-untyped-def]
    return vcv_utterances(np.random.default_rng(3), repetitions=1, rates={"normal": 1.0}, noise=0.1)[:n]


def test_free_offsets_on_one_utterance_refused_with_the_alternative(tmp_path: Path) -> None:
    s = spec(tmp_path, model={"channels": ["LLO"], "offsets": "free"})
    with pytest.raises(SpecError, match=r"\[model.offsets\] \"free\" on 1 utterance: .*confounded.*offsets = \"none\""):
        run(s, utterances=utts(1), quiet=True)
    assert small_data_notes(s, utts(2)) == []  # two utterances: allowed
    shrunk = spec(tmp_path, model={"channels": ["LLO"], "offsets": 0.5})
    notes = small_data_notes(shrunk, utts(1))
    assert len(notes) == 1 and "offsets = 0.5 on one utterance" in notes[0] and "\"none\"" in notes[0]


def test_choose_without_enough_groups(tmp_path: Path) -> None:
    s = spec(tmp_path, choose={"key": "prior_noise", "values": [0.1, 1.0], "group": "utterance"})
    with pytest.raises(SpecError, match=r"\[choose\] group = 'utterance': the 1 training utterance\(s\) form 1 .*"
                                        r"coartic compare --vary prior_noise"):
        run(s, utterances=utts(1), quiet=True)
    notes = small_data_notes(s, utts(2))
    assert len(notes) == 1 and "two folds only" in notes[0] and "one-SE rule" in notes[0]
    assert small_data_notes(s, utts(3)) == []


def test_unidentified_reasons_by_hand() -> None:
    # columns: a.target, b.target, e.target identical (only their sum is determined); a.alpha zero;
    # c.target zero (c's only parameter); d.target identified
    j = np.array([[1.0, 0.0, 1.0, 0.0, 2.0, 1.0], [2.0, 0.0, 2.0, 0.0, 1.0, 2.0]])
    names = ["a.target", "a.alpha", "b.target", "c.target", "d.target", "e.target"]
    jtj = j.T @ j
    _, v, keep = psd_pseudo_inverse(jtj, 1e-10)
    null = v[:, ~keep]
    unident = (null**2).sum(axis=1) > 0.5  # the criterion of parameter_stats
    assert list(unident) == [True, True, True, True, False, True]
    why = unidentified_reasons(names, jtj, null, unident)
    assert set(why) == {"a.target", "a.alpha", "b.target", "c.target", "e.target"}
    assert why["a.target"].startswith(("only a combination with b.target is determined",
                                       "only a combination with e.target is determined"))
    assert why["b.target"].startswith(("only a combination with a.target", "only a combination with e.target"))
    assert why["a.alpha"].startswith("the fitted trajectories do not depend on it (a zero Jacobian column)")
    assert why["c.target"].startswith("no measured sample lies within /c/'s reach")
    assert all("[[tie]]" in w and "[parameters] free" in w for w in why.values())


def test_a_phoneme_without_samples_is_said(tmp_path: Path) -> None:
    us = utts(4)  # /l/ only in "a l a", which is not measured at all: the fit leaves it out, and says so
    for u in us:
        if "l" in u.labels:
            u.valid["LLO"] = np.zeros_like(u.valid["LLO"])
    res = fit_job(spec(tmp_path), tmp_path / "out", utterances=us, quiet=True, report=False)
    assert "l" not in res.channels["LLO"].problem.phonemes
    said = "LLO: phoneme(s) l occur only in utterances with no valid LLO sample"
    assert any(n.startswith(said) for n in res.notes)
    assert any(n.startswith(said) for n in json.loads((tmp_path / "out" / "summary.json").read_text())["notes"])
    assert said in (tmp_path / "out" / "fit_report.txt").read_text()


def test_a_parameter_the_fit_does_not_depend_on_is_explained(tmp_path: Path) -> None:
    # psi (the shape rate) with sigma fixed at 0: S is off, the trajectories do not depend on psi
    res = fit_job(spec(tmp_path, parameters={"free": ["target", "psi"]}), tmp_path / "out", utterances=utts(2), quiet=True, report=False)
    st = res.channels["LLO"].stats
    # every phoneme's, the final pause's own row (#end, the default pause postures) included
    assert st is not None and sorted(st.unidentified) == ["#.psi", "#end.psi", "a.psi", "p.psi", "t.psi"]
    assert all(w.startswith("the fitted trajectories do not depend on it (a zero Jacobian column): fix it")
               for w in st.unidentified_why.values())
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert set(summary["channels"]["LLO"]["unidentified_explained"]) == set(st.unidentified)
    assert "a.psi: the fitted trajectories do not depend on it" in (tmp_path / "out" / "fit_report.txt").read_text()


def test_coartic_fit_refuses_free_offsets_on_one_recording_exit_2(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from coartic.cli import app
    from fit_helpers import german_utterance_spec

    s = german_utterance_spec(tmp_path / "one.toml", '[model]\nchannels = ["JO"]\noffsets = "free"\n'
                                                     '[parameters]\nfree = ["target"]\n')
    res = CliRunner().invoke(app, ["fit", str(s), "--out", str(tmp_path / "out")])
    said = " ".join(res.output.split())
    assert res.exit_code == 2 and "Traceback" not in res.output
    assert "[model.offsets] \"free\" on 1 utterance" in said and "use offsets = \"none\"" in said
