"""What the fit tests share: a spec from inline sections (``spec_of``), a spec file over one real
German EMA utterance (``german_utterance_spec``), and the one check of a
least-squares problem's derivatives (``check_problem_derivatives``): its Jacobian against central
finite differences of its residuals, its fused SSE and gradient against the Jacobian, and the
core's batch SSE against both."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from coartic.fit.spec import FitSpec, parse_spec


ROOT = Path(__file__).resolve().parents[2]
EMA = ROOT / "tests" / "data" / "realdata" / "emu-ema-german" / "derived"


def german_utterance_spec(path: Path, rest: str, name: str | None = None, utterance: str = "0020") -> Path:
    """A spec file at ``path`` fitting one real German EMA utterance (0020 unless ``utterance`` says
    0024; German SAMPA labels); ``rest``: the TOML that follows its [corpus] table ([model],
    [parameters]...)."""
    head = f'name = "{name}"\n' if name is not None else ""
    path.write_text(head + f'[corpus]\nfiles = ["{EMA}/dfgspp_mo1_prosody_{utterance}_ema.csv"]\n'
                    f'labels = ["{EMA}/dfgspp_mo1_prosody_{utterance}_Segment.tsv"]\nlabel_map = "german_sampa"\n' + rest)
    return path


# The model the synthetic data (coartic.fit.simulate) are made with: the paper's (centre dominance, no
# handover), fitted without the default's prior toward the data's phoneme means (docs/REAL_DATA.md),
# and the freedom the tests were written for when they give none. A spec's defaults are the model
# recommended for real recordings; a test of the mechanics states the model it means.
PAPER: dict[str, dict[str, Any]] = {
    "model": {"dominance": "centre", "handover": False, "pauses": "one"},
    "parameters": {"target_prior": "none", "free": ["target", "alpha", "theta_bw", "theta_fw"]},
}
PAPER_TOML = ('dominance = "centre"\nhandover = false\npauses = "one"\n', 'target_prior = "none"\n')  # [model], [parameters] lines


def paper(raw: dict[str, Any]) -> dict[str, Any]:
    """``raw`` (a spec as a dict) with PAPER's keys wherever it does not set them."""
    out = dict(raw)
    for section, keys in PAPER.items():
        out[section] = {**keys, **out.get(section, {})}
    return out


def spec_of(tmp_path: Path, **sections: Any) -> FitSpec:
    """A one-channel (LLO) spec with ``sections`` added to (or replacing) the minimal ones; the
    paper's model (PAPER) unless they say otherwise."""
    raw = {"corpus": {"files": ["x.csv"], "labels": ["x.lab"]}, "model": {"channels": ["LLO"]},
           "parameters": {"free": ["target"]}, **sections}
    return parse_spec(paper(raw), tmp_path / "spec.toml")


def check_problem_derivatives(prob: Any, x: np.ndarray, step: int = 1) -> None:
    """``prob``: a ChannelProblem; ``step``: check every step-th column of x (all by default)."""
    r = prob.residuals(x)
    assert r.size == prob.n_residuals
    j = prob.jacobian(x).toarray()
    h = 1e-6
    for col in range(0, x.size, step):
        e = np.zeros_like(x)
        e[col] = h
        fd = (prob.residuals(x + e) - prob.residuals(x - e)) / (2 * h)
        np.testing.assert_allclose(j[:, col], fd, rtol=1e-5, atol=1e-7)
    sse, g = prob.sse_gradient(x)
    assert sse == pytest.approx(float(r @ r), rel=1e-10)
    np.testing.assert_allclose(g, 2 * j.T @ r, rtol=1e-6, atol=1e-8)
    assert prob.sse_batch(x[None])[0] == pytest.approx(sse, rel=1e-9)  # the core's residual sums agree
