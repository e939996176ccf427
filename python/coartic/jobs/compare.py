"""The compare job: several fit specs each fitted and validated (``coartic.jobs.fit.fit_job``) and
compared by held-out RMSE and AIC/BIC (``coartic.evaluation.compare``: the rows, the model chosen per
channel, the files); ``coartic compare`` runs it.
"""

from __future__ import annotations

import math
from os import PathLike
from pathlib import Path
from typing import Sequence

from rich.console import Console

from coartic.errors import UsageError
from coartic.evaluation.baselines import BASELINES
from coartic.evaluation.compare import Comparison, Row, effective_parameters, heldout_se
from coartic.evaluation.heldout import held_out, pooled
from coartic.fit.result import FitResult
from coartic.fit.runner import check_engine_options
from coartic.fit.spec import FitSpec, load_spec
from coartic.jobs.fit import fit_job


def compare(specs: Sequence[FitSpec | str | PathLike[str]], out: str | PathLike[str] | None = None, *,
            validate: bool = True, console: Console | None = None, quiet: bool = True) -> Comparison:
    """Fit each spec (with its validation) and compare them; with ``out``, write everything there:
    one directory per spec (its fit, without the HTML report) and the comparison's files."""
    loaded = [s if isinstance(s, FitSpec) else load_spec(Path(s)) for s in specs]
    if len(loaded) < 1:
        raise UsageError("no spec to compare")
    for s in loaded:  # every spec's mistakes before the first fit, not after it
        check_engine_options(s)
    models: list[str] = []
    for i, s in enumerate(loaded):
        models.append(f"{i + 1}. {s.name} ({s.path.name})")
    rows: list[Row] = []
    results: list[FitResult] = []
    cmp = Comparison(models, rows, results)
    for model, s in zip(models, loaded):
        if console is not None and not quiet:
            console.print(f"[bold]compare[/bold]: fitting {model}", highlight=False)
        sub = None if out is None else Path(out) / _dirname(model)
        res = fit_job(s, sub, validate=validate, report=False, console=console, quiet=quiet)
        results.append(res)
        cmp.notes += [f"{model}: {n}" for n in res.notes]
        scores = held_out(res)
        held = pooled(scores)
        held_base = {b: pooled(scores, b) for b in BASELINES}
        for ch, fit in res.channels.items():
            n = fit.problem.data.n_valid
            h = held.get(ch, (math.nan, math.nan, 0))
            # (+ the speakers' offsets and scales, profiled out of x but fitted all the same)
            rows.append(Row(model, ch, fit.packing.n_free + fit.problem.n_profiled, n, fit.rmse**2 * n, fit.rmse, h[0], h[1],
                            fit.status, {b: v[ch][:2] for b, v in held_base.items() if ch in v},
                            effective_parameters(fit.problem, fit.x) + fit.problem.n_profiled,
                            heldout_se(scores, ch), s.groups.emotions))
            if not rows[-1].beats_step:
                cmp.notes.append(f"{model}: {ch}: held out, the table does not beat the step model (phoneme means, "
                                 f"no coarticulation): {h[0]:.3f} vs {rows[-1].baselines['step'][0]:.3f} mm as "
                                 f"measured, {h[1]:.3f} vs {rows[-1].baselines['step'][1]:.3f} mm offset removed")
        if res.interrupted:
            cmp.notes.append(f"interrupted while fitting {model}")
            break
    for ch in cmp.channels():
        ns = {r.n_samples for r in rows if r.channel == ch}
        if len(ns) > 1:
            cmp.notes.append(f"{ch}: the models were fitted to different numbers of samples ({sorted(ns)}): "
                             "their AIC/BIC cannot be compared")
    if out is not None and rows:
        cmp.save(out)
    return cmp


def _dirname(model: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in model).strip("_")
