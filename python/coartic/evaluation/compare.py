"""Model comparison: several fit specs side by side, by held-out RMSE and by AIC/BIC.

``coartic.jobs.compare.compare(specs, out)`` fits every spec (the fit job with its validation: the
k-fold of ``[validate] group`` or the held-out repetition and rate); ``Comparison`` tabulates per spec
and channel (``Row``): free
parameters, in-sample RMSE, held-out RMSE (pooled over the splits, as measured and with each
utterance's offset removed), and the Gaussian information criteria of the full fit

    AIC = n ln(SSE/n) + 2k,    BIC = n ln(SSE/n) + k ln n

(n valid samples, k free parameters; lower is better, and only differences between specs fitted
to the same samples mean anything, so specs on different data are flagged).

A prior or a pooling makes a free parameter cost less than one: each row also gives the *effective*
number of parameters, the trace of the fit's hat matrix tr((JᵀJ + KᵀK)⁻¹ JᵀJ) at the optimum (J the
data rows' Jacobian, K every prior row's: targets' prior, shrinkage, pooling, the emotions' deviation
prior; Hastie, Tibshirani & Friedman §7.6), plus the speakers' profiled parameters. An emotion
factor whose deviations the data pool into neutral (τ ≈ 0) adds about nothing to it.

**The model chosen per channel** (``Comparison.chosen``, held out only): the one-standard-error rule
over models, as ``[choose]`` applies it over a grid (``coartic.evaluation.choose``): among the models whose
held-out RMSE is within one standard error of the lowest, the one with the fewest effective
parameters (to 0.1; then the fewest free ones). The standard error is the lowest one's, over the
held-out utterances (``heldout_se``: each utterance a unit, its SSE and samples; the ratio
estimator's delta-method SE of the pooled MSE, carried to the RMSE). So a richer model, such as a
table with ``[model] emotions = "targets"``, is chosen only when its held-out error is lower by more
than the noise of that error, and ``Comparison.factor_lines`` says per channel whether the emotion
factor was worth its parameters. ``Comparison.save`` writes ``compare.csv``, ``compare.txt``,
``compare.png`` and ``compare.html`` (the job adds one directory per spec: its fit, as ``coartic fit``
writes it, without the HTML report). ``coartic compare`` is the command over the job
(``coartic.jobs.compare_cli``).
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field, replace
from os import PathLike
from pathlib import Path
from typing import Any, Sequence

from coartic.estimation.checks import EMOTION_MODES
from coartic.evaluation.baselines import BASELINES
from coartic.fit.result import BAR_MM, FitResult
from coartic.fit.spec import FitSpec


@dataclass
class Row:
    model: str  # the spec's name and file
    channel: str
    n_free: int
    n_samples: int
    sse: float
    rmse: float  # in-sample, mm
    heldout_rmse: float = math.nan  # pooled over the validation splits, mm
    heldout_rmse_offset_removed: float = math.nan
    status: str = ""
    # baseline -> pooled held-out (as measured, offset removed) on the same samples (coartic.evaluation.baselines)
    baselines: dict[str, tuple[float, float]] = field(default_factory=dict)
    n_effective: float = math.nan  # the trace of the hat matrix (+ profiled parameters): effective_parameters
    heldout_rmse_se: float = math.nan  # the held-out RMSE's standard error over the test utterances (heldout_se)
    emotions: str = "none"  # the spec's [model] emotions

    @property
    def beats_step(self) -> bool:
        """Held out, the table beats the step model as measured and offset removed (or there is none)."""
        from coartic.evaluation.baselines import beats_step

        step = self.baselines.get("step")
        return step is None or beats_step((self.heldout_rmse, self.heldout_rmse_offset_removed), step)

    @property
    def aic(self) -> float:
        return self.n_samples * math.log(self.sse / self.n_samples) + 2 * self.n_free

    @property
    def bic(self) -> float:
        return self.n_samples * math.log(self.sse / self.n_samples) + self.n_free * math.log(self.n_samples)

    def as_dict(self) -> dict[str, Any]:
        return {"model": self.model, "channel": self.channel, "free_parameters": self.n_free,
                "effective_parameters": self.n_effective, "emotions": self.emotions,
                "samples": self.n_samples, "rmse_mm": self.rmse, "heldout_rmse_mm": self.heldout_rmse,
                "heldout_rmse_se_mm": self.heldout_rmse_se,
                "heldout_rmse_offset_removed_mm": self.heldout_rmse_offset_removed, "aic": self.aic,
                "bic": self.bic, "status": self.status,
                **{f"heldout_{b}_{k}": (self.baselines[b][i] if b in self.baselines else math.nan)
                   for b in BASELINES for i, k in enumerate(("rmse_mm", "rmse_offset_removed_mm"))},
                "beats_step_model": self.beats_step}


@dataclass
class Comparison:
    models: list[str]
    rows: list[Row]
    results: list[FitResult]
    notes: list[str] = field(default_factory=list)

    def best(self, channel: str, key: str) -> str | None:
        """The model with the lowest ``key`` ("heldout_rmse", "aic", "bic", "rmse") on ``channel``."""
        cands = [r for r in self.rows if r.channel == channel and math.isfinite(getattr(r, key))]
        return min(cands, key=lambda r: getattr(r, key)).model if cands else None

    def channels(self) -> list[str]:
        return list(dict.fromkeys(r.channel for r in self.rows))

    def chosen(self, channel: str) -> str | None:
        """The model the one-SE rule chooses on ``channel`` (module docstring): within one standard
        error of the lowest held-out RMSE, the fewest effective parameters; None without held-out
        figures (``--no-validate``)."""
        cands = [r for r in self.rows if r.channel == channel and math.isfinite(r.heldout_rmse)]
        if not cands:
            return None
        best = min(cands, key=lambda r: r.heldout_rmse)
        limit = best.heldout_rmse + (best.heldout_rmse_se if math.isfinite(best.heldout_rmse_se) else 0.0)
        within = [r for r in cands if r.heldout_rmse <= limit]
        return min(within, key=lambda r: (round(r.n_effective, 1) if math.isfinite(r.n_effective) else r.n_free,
                                          r.n_free, r.heldout_rmse)).model

    def factor_lines(self) -> list[str]:
        """Per channel, whether ``[model] emotions = "targets"`` was worth its parameters held out
        (said when the comparison has models with and without the factor), and whether the
        emotions' own dynamics (``"targets+dynamics"``) were, against ``"targets"``."""
        out: list[str] = []
        modes = {r.emotions for r in self.rows}
        tests = [("the emotion factor", {"none"}, set(EMOTION_MODES) - {"none"}),
                 ("the emotions' own dynamics", {"targets"}, {"targets+dynamics"})]
        for what, simpler, richer in tests:
            if not (modes & simpler and modes & richer):
                continue
            for ch in self.channels():
                pick = self.chosen(ch)
                if pick is None:
                    continue
                rows = {r.model: r for r in self.rows if r.channel == ch}
                with_f = [r for r in rows.values() if r.emotions in richer and math.isfinite(r.heldout_rmse)]
                without = [r for r in rows.values() if r.emotions in simpler and math.isfinite(r.heldout_rmse)]
                if not with_f or not without:
                    continue
                a = min(without, key=lambda r: r.heldout_rmse)
                b = min(with_f, key=lambda r: r.heldout_rmse)
                worth = rows[pick].emotions in richer
                out.append(f"{ch}: {what} {'is' if what.endswith('factor') else 'are'} {'' if worth else 'not '}"
                           f"worth {'its' if what.endswith('factor') else 'their'} parameters held out: "
                           f"{b.heldout_rmse:.4f} ± {b.heldout_rmse_se:.4f} mm with {'it' if what.endswith('factor') else 'them'} "
                           f"({b.n_effective:.1f} effective of {b.n_free} free), {a.heldout_rmse:.4f} ± "
                           f"{a.heldout_rmse_se:.4f} mm without ({a.n_effective:.1f} of {a.n_free}); chosen: {pick}")
        return out

    def text(self) -> str:
        lines = [f"[[Comparison]] {len(self.models)} models"]
        lines += [f"    note: {n}" for n in self.notes]
        lines += [f"    {n}" for n in self.factor_lines()]
        for ch in self.channels():
            lines.append(f"[[{ch}]]  (chosen, one-SE rule: {self.chosen(ch)}; best held-out: "
                         f"{self.best(ch, 'heldout_rmse')}, best BIC: {self.best(ch, 'bic')})")
            for r in self.rows:
                if r.channel == ch:
                    lines.append(f"    {r.model}: k {r.n_free} (effective {r.n_effective:.1f}), RMSE {r.rmse:.4f} mm, "
                                 f"held-out {r.heldout_rmse:.4f} ± {r.heldout_rmse_se:.4f} mm "
                                 f"(offset removed {r.heldout_rmse_offset_removed:.4f}), AIC {r.aic:.1f}, "
                                 f"BIC {r.bic:.1f} [{r.status}]"
                                 + "".join(f"; {b} {v[0]:.4f} (offset removed {v[1]:.4f})" for b, v in r.baselines.items())
                                 + ("" if r.beats_step else "; WARNING: does not beat the step model"))
        return "\n".join(lines) + "\n"

    def save(self, out: str | PathLike[str]) -> dict[str, Path]:
        from coartic.outputs import atomic_write_text

        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        paths = {"csv": out / "compare.csv", "text": out / "compare.txt", "figure": out / "compare.png",
                 "html": out / "compare.html"}
        buf = io.StringIO()
        w = csv.DictWriter(buf, fieldnames=[*self.rows[0].as_dict(), "chosen"], lineterminator="\n")
        w.writeheader()
        for r in self.rows:
            w.writerow({k: (repr(v) if isinstance(v, float) else v) for k, v in r.as_dict().items()}
                       | {"chosen": self.chosen(r.channel) == r.model})
        atomic_write_text(paths["csv"], buf.getvalue())
        atomic_write_text(paths["text"], self.text())
        comparison_figure(self, paths["figure"])
        atomic_write_text(paths["html"], self.html(paths["figure"].name))
        return paths

    def html(self, figure: str) -> str:
        """A page with the table and the figure; every text from specs and data escaped."""
        import jinja2

        env = jinja2.Environment(autoescape=True)
        page = env.from_string(_PAGE)
        return page.render(models=self.models, rows=[r.as_dict() for r in self.rows], notes=self.notes,
                           figure=figure, bar=BAR_MM, factor=self.factor_lines(),
                           chosen={ch: self.chosen(ch) for ch in self.channels()},
                           best={ch: (self.best(ch, "heldout_rmse"), self.best(ch, "bic")) for ch in self.channels()})


_PAGE = """<!doctype html>
<html><head><meta charset="utf-8"><title>coartic: model comparison</title>
<style>body{font-family:sans-serif;margin:2em}table{border-collapse:collapse}td,th{border:1px solid #ccc;
padding:3px 8px;text-align:right}td:first-child,td:nth-child(2){text-align:left}.best{font-weight:bold}
.worse{color:#b00;font-weight:bold}</style>
</head><body>
<h1>Model comparison</h1>
<p>Held-out RMSE: pooled over the validation splits (data each fit did not see). AIC/BIC: of the fit to
all data, Gaussian errors; lower is better, differences matter only on the same samples. The paper's bar: {{ bar }} mm.
Baselines on the same held-out samples (as measured / offset removed): the step model (each phoneme's training mean, no
coarticulation; red where the table does not beat it) and the constant (the training mean). Effective parameters:
the trace of the hat matrix (a parameter a prior holds costs less than one). Chosen (✓): within one standard error of
the lowest held-out RMSE, the model with the fewest effective parameters.</p>
{% for n in factor %}<p><strong>{{ n }}</strong></p>{% endfor %}
{% for n in notes %}<p><em>note:</em> {{ n }}</p>{% endfor %}
<table><tr><th>model</th><th>channel</th><th>free</th><th>effective</th><th>samples</th><th>RMSE (mm)</th><th>held-out RMSE (mm) ± SE</th>
<th>held-out, offset removed</th><th>step model (held out)</th><th>constant (held out)</th><th>AIC</th><th>BIC</th><th>chosen</th><th>status</th></tr>
{% for r in rows %}<tr><td>{{ r.model }}</td><td>{{ r.channel }}</td><td>{{ r.free_parameters }}</td>
<td>{{ '%.1f' % r.effective_parameters }}</td><td>{{ r.samples }}</td>
<td>{{ '%.4f' % r.rmse_mm }}</td>
<td{% if best[r.channel][0] == r.model %} class="best"{% endif %}>{{ '%.4f' % r.heldout_rmse_mm }} ± {{ '%.4f' % r.heldout_rmse_se_mm }}</td>
<td>{{ '%.4f' % r.heldout_rmse_offset_removed_mm }}</td>
<td{% if not r.beats_step_model %} class="worse"{% endif %}>{{ '%.4f' % r.heldout_step_rmse_mm }} / {{ '%.4f' % r.heldout_step_rmse_offset_removed_mm }}</td>
<td>{{ '%.4f' % r.heldout_constant_rmse_mm }} / {{ '%.4f' % r.heldout_constant_rmse_offset_removed_mm }}</td><td>{{ '%.1f' % r.aic }}</td>
<td{% if best[r.channel][1] == r.model %} class="best"{% endif %}>{{ '%.1f' % r.bic }}</td>
<td>{% if chosen[r.channel] == r.model %}✓{% endif %}</td><td>{{ r.status }}</td></tr>
{% endfor %}</table>
<p><img src="{{ figure }}" alt="held-out and in-sample RMSE per model and channel"></p>
</body></html>
"""


def comparison_figure(cmp: Comparison, path: Path) -> Path:
    """Grouped bars per channel: in-sample (light) and held-out (dark) RMSE of each model."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from coartic.outputs import save_figure

    chans = cmp.channels()
    fig, axes = plt.subplots(1, len(chans), figsize=(max(4.0, 1.2 * len(cmp.models) + 2) * len(chans), 4),
                             squeeze=False)
    for ax, ch in zip(axes[0], chans):
        rows = [r for r in cmp.rows if r.channel == ch]
        x = np.arange(len(rows))
        ax.bar(x - 0.2, [r.rmse for r in rows], 0.4, color="#9ecae1", label="in-sample")
        ax.bar(x + 0.2, [r.heldout_rmse for r in rows], 0.4, color="#3182bd", label="held-out")
        ax.axhline(BAR_MM, color="red", lw=0.8, ls="--")
        ax.set_xticks(x, [f"{i + 1}" for i in range(len(rows))])
        ax.set_xlabel("model (numbered as in the table)")
        ax.set_ylabel(f"{ch} RMSE (mm)")
        ax.legend(fontsize=7)
    fig.tight_layout()
    return save_figure(fig, path)


# Spec settings ``--vary`` may scan (e.g. the prior strength, chosen by held-out RMSE instead of by hand).
VARIABLE: dict[str, type] = {"prior_noise": float, "target_margin": float, "apex_fraction": float,
                             "edge_extent": float, "beta": float, "plateau_fraction": float, "offsets": str,
                             "variant": str, "dominance": str, "emotions": str}


def vary(spec: FitSpec, key: str, values: Sequence[str]) -> list[FitSpec]:
    """One spec per value of the setting ``key`` (one of ``VARIABLE``), named after it; the values
    are checked as the spec's own would be (by parsing the spec with each)."""
    from coartic.errors import SpecError
    from coartic.fit.spec import parse_spec, read_document

    from coartic.fit.spec import choose_base

    if choose_base(key) == "shrink.sd":  # the [[shrink]] sd (all tables, or "shrink #N.sd" one)
        from coartic.fit.choose import set_value

        out = []
        for v in values:
            try:
                sd = float(v)
            except ValueError:
                raise SpecError(f"--vary {key}={v}: not a number") from None
            if not (sd > 0 and math.isfinite(sd)):
                raise SpecError(f"--vary {key}={v}: an sd must be a positive number")
            made = set_value(spec, key, sd)
            shrinks = spec.priors.shrinks
            if key == "shrink.sd" and not shrinks or key != "shrink.sd" and made.priors.shrinks == shrinks:
                raise SpecError(f"--vary {key}: {spec.path} has no such [[shrink]] table")
            out.append(replace(made, name=f"{spec.name}, {key} = {v}"))
        return out
    if key not in VARIABLE:
        raise SpecError(f"--vary {key}: not a setting compare can vary (known: {', '.join(VARIABLE)}, shrink.sd)")
    raw = read_document(spec.path)
    section = "parameters" if key in ("prior_noise", "target_margin") else "model"
    out = []
    for v in values:
        value: Any = v
        if key == "offsets":
            try:
                value = float(v)
            except ValueError:
                value = v
        elif VARIABLE[key] is float:
            try:
                value = float(v)
            except ValueError:
                raise SpecError(f"--vary {key}={v}: not a number") from None
        doc = dict(raw)
        doc[section] = dict(doc.get(section, {})) | {key: value}
        doc["name"] = f"{spec.name}, {key} = {v}"
        out.append(parse_spec(doc, spec.path))
    return out


def effective_parameters(problem: Any, x: Any) -> float:
    """The trace of the hat matrix of a channel's fit at ``x``: tr(H⁺ JᵀJ), H = JᵀJ + KᵀK the
    Gauss-Newton Hessian of the whole objective (J the data rows, K every prior row after them),
    H⁺ its pseudo-inverse (a direction nothing determines counts 0). Without priors: the number of
    identified free parameters; a prior that holds a parameter at its mean: 0 for it. Invariant to
    the parameterisation (log α or α), as a trace of a product with the inverse is."""
    import numpy as np

    from coartic.estimation.parameters import psd_pseudo_inverse

    j = problem.jacobian(x)
    n_data = problem.data.corpus.n_samples
    jd = j[:n_data]
    hd = np.asarray((jd.T @ jd).toarray())
    h = np.asarray((j.T @ j).toarray())
    if h.size == 0:
        return 0.0
    return float(np.sum(psd_pseudo_inverse(h)[0] * hd.T))


def heldout_se(scores: Sequence[Any], channel: str) -> float:
    """The standard error of the pooled held-out RMSE of ``channel`` over its test utterances
    (every split's, each a unit with its SSE e_u and samples n_u): the pooled MSE m = Σe/Σn is a
    ratio estimator, whose delta-method SE is √(U/(U−1) Σ(e_u − m n_u)²)/Σn; the RMSE's is that
    over 2√m. NaN with fewer than two utterances (or none recorded)."""
    units = [v for sc in scores if sc.channel == channel for v in getattr(sc, "utterance_sse", {}).values() if v[1] > 0]
    if len(units) < 2:
        return math.nan
    n = float(sum(k for _, k in units))
    m = sum(e for e, _ in units) / n
    if m <= 0:
        return 0.0
    u = len(units)
    var = u / (u - 1) * sum((e - m * k) ** 2 for e, k in units) / n**2
    return math.sqrt(var) / (2.0 * math.sqrt(m))
