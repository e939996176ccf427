"""Does the Laplace proposal ("de+laplace") sample the calibration posteriors in fewer steps than "de"?

Measured by measuring what test_mcmc_calibration.py runs, each posterior with both moves in the same
process (same machine load), CPU time per run:

* the session test: ``coartic mcmc`` on its spec (the synthetic session's /p t/ trials, repetition 1;
  joint LLO and JO posteriors, 26 dimensions, 54 walkers, 2 ensembles; checks every 1000 steps from
  6000, and again with the first check at 3000), the steps and tau_max at convergence, and the
  coverage of the truth;
* the small test's per-consonant posteriors (/p t l/, 4 dimensions, 10 walkers; checks every 500
  steps from 1000).

Run: PYTHONPATH=python .venv/bin/python bench/mcmc_laplace.py   (output in bench/results/mcmc_laplace.txt)
"""

from __future__ import annotations

import json
import re
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "python"))


def session_runs(tmp: Path) -> None:
    import coartic.fit.spec
    from typer.testing import CliRunner

    from coartic.cli import app
    from coartic.jobs.fit import fit_job
    from coartic.synthetic_cli import load_generator
    from test_mcmc_calibration import SESSION_SPEC, session_coverage

    coartic.fit.spec.DEFAULT_STARTS = 1  # as the tests' conftest
    gen = load_generator()
    gen.plot_overview = lambda *a, **k: None
    manifest = gen.generate(tmp / "session", quick=True, progress=False, consonants=["p", "t"])
    base = SESSION_SPEC.format(manifest=manifest, truth=gen.GROUND_TRUTH)
    (tmp / "spec.toml").write_text(base)
    fit_job(tmp / "spec.toml", tmp / "fit", quiet=True, report=False)
    for tag, moves, min_steps in (("de", "de", 6000), ("de+laplace", "de+laplace", 6000), ("de+laplace, first check 3000", "de+laplace", 3000)):
        text = re.sub(r"^min_steps = .*$", f"min_steps = {min_steps}", base, flags=re.M).replace("[mcmc]\n", f'[mcmc]\nmoves = "{moves}"\n')
        spec, out = tmp / f"spec_{len(tag)}.toml", tmp / f"mcmc_{len(tag)}"
        spec.write_text(text)
        t = time.process_time()
        r = CliRunner().invoke(app, ["mcmc", str(spec), "--fit", str(tmp / "fit"), "--out", str(out), "--strict", "--quiet"])
        cpu = time.process_time() - t
        identified, covered, covered_68, _ = session_coverage(out, gen.GROUND_TRUTH)
        parts = []
        for ch in ("LLO", "JO"):
            c = json.loads((out / ch / "_joint" / "summary.json").read_text())["convergence"]
            parts.append(f"{ch} {c['n_steps']} steps tau_max {c['tau_max']:.0f} acceptance {c['acceptance'][0]:.2f}")
        print(f"session, {tag:30s} exit {r.exit_code}  {'; '.join(parts)};  {cpu:.1f} CPU-s;  "
              f"covered {covered} of {identified} (68 %: {covered_68})", flush=True)


def small_runs(tmp: Path) -> None:
    import mcmc_data
    from coartic import _core
    from coartic.mcmc.posterior import phoneme_posterior
    from coartic.mcmc.run import fixed_noise, sample_posterior
    from coartic.mcmc.sampler import SamplerSettings

    options = _core.ModelOptions("modified")
    data = mcmc_data.channel(mcmc_data.utterances(repetitions=1, seed=5, pause=0.12))
    packing = mcmc_data.packing(("target", "theta_bw", "theta_fw", "k_r"))
    noise = fixed_noise(data, packing, options)
    for moves in ("de", "de+laplace"):
        t = time.process_time()
        parts = []
        for c in ("p", "t", "l"):
            post = phoneme_posterior(data, packing, options, c, noise=noise)
            s = SamplerSettings(n_walkers=10, n_ensembles=2, chunk_steps=500, min_steps=1000, max_steps=8000, seed=1, moves=moves)
            rep = sample_posterior(post, tmp / f"small_{moves}_{c}", s, c, make_plots=False, progress=False).result.report
            assert rep is not None
            parts.append(f"/{c}/ {rep.n_steps} steps tau_max {rep.tau_max:.1f} ESS {min(rep.ess_bulk):.0f}"
                         f"{'' if rep.converged else ' NOT CONVERGED'}")
        print(f"small, {moves:12s} {'; '.join(parts)};  {time.process_time() - t:.1f} CPU-s", flush=True)


if __name__ == "__main__":
    with tempfile.TemporaryDirectory() as d:
        small_runs(Path(d))
        session_runs(Path(d))
