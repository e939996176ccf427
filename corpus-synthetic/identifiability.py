"""How well can a fit recover the ground truth from a session? The Fisher information says.

    python corpus-synthetic/identifiability.py SESSION [--free all|no-shape|core] [--sigma 0.135]

For each channel, the Jacobian of the model at the ground truth over every trial of SESSION (the
output of ``coartic corpus synth``) gives the Fisher information J^T J / sigma^2 of the free
parameters, and its inverse the smallest standard errors any unbiased fit can reach with noise
sigma (the channel noise of the session, ~0.13-0.14 mm). alpha, theta and psi are taken in log form,
as the fitter does; alpha of the reference phoneme and beta are fixed.

``--free`` chooses what the fit would free:
  all       every parameter: sigma, which scales the target (S = 1 + sigma ...), is then nearly
            collinear with it wherever sigma = 0, so targets lose precision;
  no-shape  sigma and psi only where the ground truth has sigma != 0 (the default);
  core      target, alpha, theta and k_R only.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Annotated

import numpy as np
import scipy.sparse as sp
import typer
from rich.console import Console
from rich.progress import track
from rich.table import Table

from coartic import _core
from coartic.model import Utterance, build_corpus, model_options
from coartic.table import CHANNELS, N_PARAMS, PARAMETERS, ParameterTable

LOG_FORM = frozenset({"alpha", "theta_bw", "theta_fw", "psi"})
CRITICAL = ("p", "b", "m", "f", "v")


def free_parameters(table: ParameterTable, channel: str, phonemes: list[str], mode: str) -> list[tuple[int, str, str]]:
    """(column of the Jacobian, phoneme, parameter) of every parameter the fit would free."""
    ref = table.channels[channel].reference_phoneme
    out = []
    for p, ph in enumerate(phonemes):
        shaped = table.values[ph][channel]["sigma"] != 0.0
        for k, name in enumerate(PARAMETERS):
            if name == "alpha" and ph == ref:
                continue
            if name in ("sigma", "psi") and (mode == "core" or (mode == "no-shape" and not shaped)):
                continue
            if name in ("c_bw", "c_fw", "delta") and mode == "core":
                continue
            out.append((p * N_PARAMS + k, ph, name))
    return out


def standard_errors(
    table: ParameterTable, channel: str, utterances: list[Utterance], sigma: float, mode: str
) -> dict[tuple[str, str], float]:
    phonemes = table.phonemes_for(channel)
    corpus = build_corpus(utterances, phonemes)
    params, beta = table.to_matrix(channel, phonemes)
    values, indptr, indices, data = _core.jacobian(
        corpus, np.ascontiguousarray(params), beta, model_options(table, channel)
    )
    jac = sp.csr_matrix((data, indices, indptr), shape=(len(values), len(phonemes) * N_PARAMS + 1))
    free = free_parameters(table, channel, phonemes, mode)
    a = jac[:, [c for c, _, _ in free]].toarray()
    for j, (c, _, name) in enumerate(free):
        if name in LOG_FORM:
            a[:, j] *= params[c // N_PARAMS, c % N_PARAMS]  # d/d(log x) = x d/dx
    fisher = a.T @ a / sigma**2
    # pinv: a parameter with no effect at all (sigma of a zero target) gets no finite error.
    cov = np.linalg.pinv(fisher, rcond=1e-13)
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    dead = ~np.any(a != 0.0, axis=0)
    se[dead] = np.inf
    return {(ph, name): float(se[j]) for j, (_, ph, name) in enumerate(free)}


def main(
    session: Annotated[Path, typer.Argument(help="A session written by `coartic corpus synth`.")],
    free: Annotated[str, typer.Option(help="all | no-shape | core")] = "no-shape",
    sigma: Annotated[float, typer.Option(help="Channel noise (mm).")] = 0.135,
) -> None:
    if free not in ("all", "no-shape", "core"):
        raise typer.BadParameter(f"--free must be all, no-shape or core, not {free!r}")
    table = ParameterTable.load(session / "ground_truth.json")
    with open(session / "manifest.csv", newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    utterances = []
    for r in track(rows, description="reading the truth files", transient=True):
        with np.load(session / r["truth"]) as z:
            utterances.append(Utterance(list(z["labels"]), z["starts"], z["ends"], z["times"], r["file"]))
    out = Table(title=f"Smallest standard errors at the ground truth ({len(rows)} trials, noise {sigma} mm, free: {free})")
    for col in ("channel", "target s.e. max (mm)", "worst target", "k_R s.e. max where k_R = 1", "worst log-theta s.e."):
        out.add_column(col)
    for ch in CHANNELS:
        se = standard_errors(table, ch, utterances, sigma, free)
        targets = {ph: s for (ph, name), s in se.items() if name == "target"}
        worst = max(targets, key=lambda ph: targets[ph])
        kr_one = [se[(ph, "k_r")] for ph in CRITICAL if table.values[ph][ch]["k_r"] == 1.0]
        theta = max(((s, ph, n) for (ph, n), s in se.items() if n.startswith("theta")), default=(np.nan, "", ""))
        out.add_row(ch, f"{targets[worst]:.3f}", worst, f"{max(kr_one):.4f}" if kr_one else "-", f"{theta[0]:.2f} ({theta[1]} {theta[2]})")
    Console(width=120).print(out)


if __name__ == "__main__":
    typer.run(main)
