"""Figures of a fit (matplotlib, Agg): trajectories with dominance functions, residuals, RMSE maps."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from coartic.fit.result import BAR_MM, ChannelFit, FitResult  # noqa: E402
from coartic.model import segment_weights  # noqa: E402
from coartic.table import ParameterTable  # noqa: E402

# The paper's Figure 1: lower lip opening for /a d a/, /a dz a/, /a l a/.
FIGURE1_STIMULI = ("a d a", "a dz a", "a l a")


def pick_utterances(fit: ChannelFit, stimuli: Sequence[str], rate: str = "normal") -> list[int]:
    """Index of the first utterance of each stimulus (at ``rate`` when the corpus has rates)."""
    out = []
    for s in stimuli:
        cands = [i for i, u in enumerate(fit.problem.data.utterances)
                 if u.meta.get("stimulus") == s and u.meta.get("rate", rate) == rate]
        if cands:
            out.append(cands[0])
    return out


def trajectory_figure(fit: ChannelFit, table: ParameterTable, utterances: Sequence[int]) -> Figure:
    """Measured vs modelled channel per utterance, the normalised dominances drawn underneath.

    The lower panel shows w_i(t) = S_i R_i D_i / Σ_j R_j D_j of every segment (F = Σ T_i w_i), as the
    paper's Figure 1 draws the dominance functions under the lower lip opening.
    """
    d = fit.problem.data
    n = max(len(utterances), 1)
    fig, axes = plt.subplots(2, n, figsize=(4.2 * n, 5.2), sharex="col", squeeze=False,
                             gridspec_kw={"height_ratios": [2.2, 1]})
    assert fit.fitted is not None
    for col, u in enumerate(utterances):
        utt = d.utterances[u]
        sl = d.utterance_samples(u)
        t = utt.times
        y = np.where(d.weights[sl] > 0, d.observed[sl], np.nan)
        top, bottom = axes[0, col], axes[1, col]
        top.plot(t, y, ".", ms=3, color="0.35", label="measured")
        top.plot(t, fit.fitted[sl], "-", color="C3", lw=1.6, label="model")
        rm = float(np.sqrt(np.nanmean((fit.fitted[sl] - y) ** 2)))
        top.set_title(f"/{utt.meta.get('stimulus', utt.name)}/  {utt.meta.get('rate', '')}  RMSE {rm:.2f} mm",
                      fontsize=9)
        w = segment_weights(table, d.channel, list(utt.labels), utt.starts, utt.ends, t)
        for i, (lab, s, e) in enumerate(zip(utt.labels, utt.starts, utt.ends)):
            for ax in (top, bottom):
                ax.axvline(s, color="0.85", lw=0.6, zorder=0)
            top.text(0.5 * (s + e), 1.0, lab, transform=top.get_xaxis_transform(), ha="center", va="bottom",
                     fontsize=8)
            bottom.plot(t, w[i], lw=1.2, label=lab)
            bottom.fill_between(t, 0, w[i], alpha=0.12)
        bottom.set_ylim(0, 1.05)
        bottom.set_xlabel("time (s)")
        if col == 0:
            top.set_ylabel(f"{d.channel} (mm)")
            bottom.set_ylabel("weight of target")
            top.legend(fontsize=7, loc="best")
    fig.tight_layout()
    return fig


def residual_figure(result: FitResult) -> Figure:
    """Histogram of model − measured per channel, with the RMSE and the 0.3 mm bar."""
    chans = list(result.channels)
    fig, axes = plt.subplots(1, len(chans), figsize=(2.6 * len(chans), 2.8), squeeze=False, sharey=False)
    for ax, ch in zip(axes[0], chans):
        fit = result.channels[ch]
        r = fit.residuals()
        r = r[np.isfinite(r)]
        lim = max(4 * float(np.std(r)), BAR_MM * 1.5)
        ax.hist(np.clip(r, -lim, lim), bins=60, range=(-lim, lim), color="C0", alpha=0.8, density=True)
        xs = np.linspace(-lim, lim, 200)
        sd = float(np.std(r)) or 1e-9
        ax.plot(xs, np.exp(-0.5 * (xs / sd) ** 2) / (sd * np.sqrt(2 * np.pi)), color="k", lw=0.8)
        for b in (-BAR_MM, BAR_MM):
            ax.axvline(b, color="C3", ls="--", lw=0.8)
        ax.set_title(f"{ch}: RMSE {fit.rmse:.3f} mm", fontsize=9)
        ax.set_xlabel("model − measured (mm)")
    axes[0, 0].set_ylabel("density")
    fig.tight_layout()
    return fig


def rmse_map_figure(result: FitResult) -> Figure | None:
    """Consonant × vowel RMSE per channel; cells at or above the 0.3 mm bar are outlined."""
    chans = list(result.channels)
    first = result.channels[chans[0]]
    metas = [u.meta for u in first.problem.data.utterances]
    if not all("consonant" in m and "vowel" in m for m in metas):
        return None
    cons = list(dict.fromkeys(m["consonant"] for m in metas))
    vows = list(dict.fromkeys(m["vowel"] for m in metas))
    fig, axes = plt.subplots(1, len(chans), figsize=(1.0 + 1.3 * len(chans) * max(1, len(vows) / 3), 0.25 * len(cons) + 1.6),
                             squeeze=False)
    vmax = max(BAR_MM * 1.5, max(f.rmse for f in result.channels.values()) * 1.5)
    im = None
    for ax, ch in zip(axes[0], chans):
        by = result.channels[ch].rmse_by(("consonant", "vowel"))
        grid = np.full((len(cons), len(vows)), np.nan)
        for (c, v), (rm, _) in by.items():
            if c in cons and v in vows:
                grid[cons.index(c), vows.index(v)] = rm
        im = ax.imshow(grid, aspect="auto", cmap="viridis", vmin=0, vmax=vmax)
        for i, j in np.argwhere(grid >= BAR_MM):
            ax.add_patch(plt.Rectangle((j - 0.5, i - 0.5), 1, 1, fill=False, ec="red", lw=1.5))
        ax.set_xticks(range(len(vows)), vows)
        ax.set_yticks(range(len(cons)), cons if ax is axes[0, 0] else [], fontsize=7)
        ax.set_title(ch, fontsize=9)
    if im is not None:
        fig.colorbar(im, ax=axes[0].tolist(), label="RMSE (mm)", shrink=0.8)
    return fig


def truth_figure(result: FitResult, truth: ParameterTable) -> Figure | None:
    """Fitted against ground-truth targets and k_R (synthetic sessions, where the truth is known)."""
    pts_t, pts_k = [], []
    for ch, fit in result.channels.items():
        if ch not in truth.channels:
            continue
        for i, ph in enumerate(fit.phonemes):
            row = truth.values.get(ph, {}).get(ch)
            if row is None:
                continue
            pts_t.append((row["target"], fit.params[i, 0], ch))
            pts_k.append((row["k_r"], fit.params[i, 6], ch))
    if not pts_t:
        return None
    fig, (a, b) = plt.subplots(1, 2, figsize=(9, 4))
    chans = list(dict.fromkeys(c for _, _, c in pts_t))
    for k, ch in enumerate(chans):
        tt = np.array([(x, y) for x, y, c in pts_t if c == ch])
        kk = np.array([(x, y) for x, y, c in pts_k if c == ch])
        a.plot(tt[:, 0], tt[:, 1], "o", ms=3.5, color=f"C{k}", label=ch)
        b.plot(kk[:, 0], kk[:, 1], "o", ms=3.5, color=f"C{k}", label=ch)
    for ax, name in ((a, "target (mm)"), (b, "k_R")):
        lo, hi = ax.get_xlim()
        ax.plot([lo, hi], [lo, hi], color="0.5", lw=0.8)
        ax.set_xlabel(f"true {name}")
        ax.set_ylabel(f"fitted {name}")
    a.legend(fontsize=7)
    fig.tight_layout()
    return fig


def save(fig: Figure, path: Path) -> Path:
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
