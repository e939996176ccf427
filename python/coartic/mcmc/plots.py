"""Pictures of a posterior: corner plot, traces, and the posterior predictive band over the data."""

from __future__ import annotations

import html
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Sequence

import numpy as np
from numpy.typing import NDArray

from coartic.extras import require

if TYPE_CHECKING:
    from coartic.mcmc.posterior import LogPosterior
    from coartic.mcmc.sampler import SamplingResult
    from coartic.mcmc.summary import ParameterSummary

PREDICTIVE_DRAWS = 200


def pyplot() -> ModuleType:
    """matplotlib's pyplot (Agg), imported by the figures only: a posterior without plots (``[mcmc] plots =
    false``, coartic batch's posterior units) writes its HTML fragment without it, and a fresh process
    (a batch worker) saves matplotlib's import, about 0.5 CPU-s."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def corner_plot(result: SamplingResult, start: NDArray[np.float64], path: Path, title: str = "") -> Path:
    """Corner plot of the sampling coordinates; the least-squares optimum drawn as the 'truth' lines."""
    require("mcmc", "a corner plot")
    plt = pyplot()  # the Agg backend before corner draws
    import corner

    draws = result.draws()
    fig = corner.corner(
        draws,
        labels=result.names,
        truths=np.asarray(start),
        truth_color="tab:red",
        quantiles=[0.025, 0.5, 0.975],
        show_titles=True,
        title_fmt=".3g",
        title_kwargs={"fontsize": 8},
        label_kwargs={"fontsize": 8},
        plot_datapoints=False,
    )
    if title:
        fig.suptitle(f"{title}\n(red: least-squares optimum)", fontsize=10, y=1.02)
    fig.savefig(path, dpi=80, bbox_inches="tight")
    plt.close(fig)
    return path


def trace_plot(result: SamplingResult, path: Path, title: str = "", max_walkers: int = 8) -> Path:
    """One panel per coordinate: a few walkers of each ensemble, the burn-in shaded."""
    plt = pyplot()
    dim = len(result.names)
    fig, axes = plt.subplots(dim, 1, figsize=(9, 1.3 * dim + 0.6), sharex=True, squeeze=False)
    colors = plt.get_cmap("tab10")
    burn = result.report.burn_in if result.report else 0
    for j, ax in enumerate(axes[:, 0]):
        for e, chain in enumerate(result.chains):
            ax.plot(chain[:, :max_walkers, j], color=colors(e % 10), lw=0.4, alpha=0.6)
        ax.axvspan(0, burn, color="0.85", zorder=0)
        ax.set_ylabel(result.names[j], fontsize=7, rotation=0, ha="right", va="center")
        ax.tick_params(labelsize=7)
    axes[-1, 0].set_xlabel("step (grey: burn-in; one colour per ensemble)")
    verdict = "converged" if result.converged else "NOT CONVERGED"
    fig.suptitle(f"{title} traces: {verdict}", fontsize=10, color="black" if result.converged else "tab:red")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def predictive_plot(
    posterior: LogPosterior,
    result: SamplingResult,
    start: NDArray[np.float64],
    path: Path,
    title: str = "",
    utterances: Sequence[int] | None = None,
    seed: int = 0,
) -> Path:
    """Measured trajectories with the posterior predictive median, 68 % and 95 % bands (model
    uncertainty plus σ_n noise and the per-utterance offsets) and the least-squares fit, for a few utterances."""
    data = posterior.data
    draws = result.draws()
    rng = np.random.default_rng(seed)
    pick = draws[rng.choice(len(draws), size=min(PREDICTIVE_DRAWS, len(draws)), replace=False)]
    model = posterior.predict(pick)
    noisy = model + posterior.sigma_n(pick)[:, None] * rng.standard_normal(model.shape)
    # each utterance's offset is one draw shared by its samples
    offsets = posterior.offsets(pick)[:, None] * rng.standard_normal((len(pick), len(data.utterances)))
    noisy += np.repeat(offsets, np.diff(data.sample_offsets), axis=1)
    band = np.percentile(noisy, [2.5, 16, 50, 84, 97.5], axis=0)
    best = posterior.predict(np.asarray(start)[None])[0]
    n_utt = len(data.utterances)
    chosen = list(utterances) if utterances is not None else list(range(min(n_utt, 6)))
    ncol = 2 if len(chosen) > 1 else 1
    nrow = int(np.ceil(len(chosen) / ncol))
    plt = pyplot()
    fig, axes = plt.subplots(nrow, ncol, figsize=(5.5 * ncol, 2.6 * nrow), squeeze=False)
    for ax, u in zip(axes.ravel(), chosen):
        sl = data.utterance_samples(u)
        utt = data.utterances[u]
        t = utt.times
        ax.fill_between(t, band[0, sl], band[4, sl], color="tab:blue", alpha=0.2, lw=0, label="95 %")
        ax.fill_between(t, band[1, sl], band[3, sl], color="tab:blue", alpha=0.35, lw=0, label="68 %")
        ax.plot(t, band[2, sl], color="tab:blue", lw=1, label="posterior median")
        ax.plot(t, best[sl], color="tab:red", lw=0.8, ls="--", label="least squares")
        ok = data.weights[sl] > 0
        ax.plot(t[ok], data.observed[sl][ok], ".", color="k", ms=2, label="measured")
        for lab, s, e in zip(utt.labels, utt.starts, utt.ends):
            ax.axvline(s, color="0.8", lw=0.5)
            ax.text(0.5 * (s + e), 1.0, lab, transform=ax.get_xaxis_transform(), ha="center", va="bottom", fontsize=7)
        ax.set_title(utt.name, fontsize=8, pad=10)
        ax.tick_params(labelsize=7)
    for ax in axes.ravel()[len(chosen):]:
        ax.axis("off")
    axes[0, 0].legend(fontsize=6, loc="best")
    fig.suptitle(f"{title}: posterior predictive ({data.channel}, mm vs s)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def html_fragment(
    title: str,
    images: Sequence[Path],
    summaries: Sequence[ParameterSummary],
    verdict: str,
    converged: bool,
    base: Path,
) -> str:
    """A self-contained HTML <section> (images referenced relative to ``base``) for the report."""
    rows = []
    for s in summaries:
        q = s.quantiles
        rows.append(
            "<tr>"
            f"<td>{html.escape(s.name)}</td><td>{s.start:.4g}</td><td>{q['q50']:.4g}</td>"
            f"<td>[{q['q16']:.4g}, {q['q84']:.4g}]</td><td>[{q['q2.5']:.4g}, {q['q97.5']:.4g}]</td>"
            f"<td>{'yes' if s.identified else 'no'}</td><td>{s.rhat:.3f}</td><td>{s.ess_bulk:.0f}</td>"
            "</tr>"
        )
    imgs = "\n".join(
        f'<img src="{html.escape(str(p.relative_to(base)))}" alt="{html.escape(p.stem)}" style="max-width:100%">' for p in images
    )
    colour = "green" if converged else "red"
    return (
        f'<section class="mcmc"><h3>{html.escape(title)}</h3>\n'
        f'<p style="color:{colour}"><b>{html.escape(verdict)}</b></p>\n'
        "<table><tr><th>parameter</th><th>least squares</th><th>median</th><th>68 %</th><th>95 %</th>"
        "<th>identified</th><th>R-hat</th><th>ESS</th></tr>\n" + "\n".join(rows) + "\n</table>\n" + imgs + "\n</section>\n"
    )
