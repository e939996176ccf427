"""Figures of a fit (matplotlib, Agg): trajectories with dominance functions, residuals, RMSE maps."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Rectangle  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

from coartic.evaluation.heldout import held_out, pooled  # noqa: E402
from coartic.fit.result import BAR_MM, ChannelFit, FitResult  # noqa: E402
from coartic.model import Utterance, segment_weights  # noqa: E402
from coartic.runtime.preview import MAX_SEGMENT_BOUNDARIES, MAX_SEGMENT_LABELS  # noqa: E402
from coartic.pauses import PAUSE_PHONEMES, is_pause  # noqa: E402
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


# Utterances with at most this many segments (the VCV stimuli) are drawn side by side, as in the
# paper's Figure 1; a longer one (a sentence) gets a row of its own, as wide as its segments need.
SIDE_BY_SIDE_SEGMENTS = 8
LABEL_FONT = 8  # points
MIN_SEGMENT_WIDTH_IN = 0.22  # the median segment gets at least this much width (inches)
# Bounded work for very long utterances (the same bounds as the runtime's plots): boundaries as one
# line collection up to MAX_SEGMENT_BOUNDARIES, labels up to MAX_SEGMENT_LABELS segments, and the
# weight panel (segments x samples values) up to MAX_WEIGHT_VALUES; past them left out, and said.
MAX_WEIGHT_VALUES = 20_000_000


def utterance_title(utt: Utterance) -> str:
    """Slashes only around a phonemic transcription (a stimulus such as "a p a" whose every token is
    one of the utterance's phonemes), never around a file name or a sentence in letters:
    /a p a/ normal, but dfgspp_mo1_prosody_0020_ema."""
    stim = utt.meta.get("stimulus")
    phonemic = bool(stim) and set(str(stim).split()) <= set(utt.labels)
    title = f"/{stim}/" if phonemic else (str(stim) if stim else utt.name)
    rate = utt.meta.get("rate")
    return f"{title}  {rate}" if rate else title


def _long(utts: Sequence[Utterance]) -> bool:
    return any(len(u.labels) > SIDE_BY_SIDE_SEGMENTS for u in utts)


def _row_width(utts: Sequence[Utterance]) -> float:
    """Inches for one utterance per row: the median segment at least MIN_SEGMENT_WIDTH_IN wide."""
    widths = []
    for u in utts:
        d = np.asarray(u.ends) - np.asarray(u.starts)
        d = d[d > 0]
        span = float(u.ends[-1] - u.starts[0]) if len(u.labels) else 1.0
        if d.size:
            widths.append(span / float(np.median(d)) * MIN_SEGMENT_WIDTH_IN)
    return float(np.clip(max(widths, default=10.0) + 1.2, 9.0, 26.0))


def _panels(utts: Sequence[Utterance], rows_per: int, height: float,
            ratios: Sequence[float]) -> tuple[Figure, NDArray[np.object_], float]:
    """A figure (constrained layout) with ``rows_per`` panels per utterance: utterances side by
    side when short, each in a row of its own when long. Returns the figure, the axes indexed
    [panel, utterance] and the estimated width of one panel in inches (for the segment labels)."""
    n = max(len(utts), 1)
    axes = np.empty((rows_per, n), dtype=object)
    if _long(utts):
        width = _row_width(utts)
        fig = plt.figure(figsize=(width, height * n), layout="constrained")
        subfigs = fig.subfigures(n, 1, squeeze=False)[:, 0]
        for k, sf in enumerate(subfigs):
            ax = sf.subplots(rows_per, 1, sharex=True, squeeze=False, height_ratios=list(ratios))
            axes[:, k] = ax[:, 0]
        return fig, axes, width - 1.3
    fig = plt.figure(figsize=(4.2 * n, height), layout="constrained")
    ax = fig.subplots(rows_per, n, sharex="col", squeeze=False, height_ratios=list(ratios))
    axes[:, :] = ax
    return fig, axes, 4.2 - 1.0


def segment_labels(ax: Any, labels: Sequence[str], starts: Sequence[float] | NDArray[np.float64],
                   ends: Sequence[float] | NDArray[np.float64], width_in: float, fontsize: float = LABEL_FONT) -> int:
    """Each segment's label above the axes at its centre, stacked in as many lines as needed so
    that no two overlap (short segments of a sentence) on axes ``width_in`` inches wide; returns
    the number of lines used."""
    x0, x1 = ax.get_xlim()
    char = 0.62 * fontsize / 72 * (x1 - x0) / max(width_in, 1e-6)  # one character, in data units
    line_end: list[float] = []
    for lab, s, e in zip(labels, starts, ends):
        c = 0.5 * (float(s) + float(e))
        half = 0.5 * char * (len(lab) + 0.8)
        line = next((k for k, end in enumerate(line_end) if c - half >= end), len(line_end))
        if line == len(line_end):
            line_end.append(c + half)
        line_end[line] = c + half
        ax.annotate(lab, xy=(c, 1.0), xycoords=("data", "axes fraction"), xytext=(0, 2 + line * (fontsize + 1)),
                    textcoords="offset points", ha="center", va="bottom", fontsize=fontsize)
    return len(line_end)


def phoneme_colours(phonemes: Sequence[str]) -> dict[str, Any]:
    """One colour per phoneme (the pauses greys), the same in every panel of a figure."""
    palette = [plt.get_cmap(name)(k) for name in ("tab20", "tab20b", "tab20c") for k in range(20)]
    others = [p for p in dict.fromkeys(phonemes) if not is_pause(p)]
    colours: dict[str, Any] = {p: palette[k % len(palette)] for k, p in enumerate(others)}
    for k, p in enumerate(PAUSE_PHONEMES):  # '#' (initial), '#end', '#mid': three greys
        if p in phonemes:
            colours[p] = (0.6 - 0.15 * k, 0.6 - 0.15 * k, 0.6 - 0.15 * k, 1.0)
    return colours


def _bottom_legend(fig: Figure, handles: list[Any], labels: list[str], title: str) -> None:
    """A legend under all panels, in as many columns as the figure's width holds."""
    ncol = max(1, min(len(labels), int(fig.get_size_inches()[0] / 0.75)))
    fig.legend(handles, labels, loc="outside lower center", ncol=ncol, fontsize=7, title=title, title_fontsize=7,
               frameon=False, handlelength=1.2, columnspacing=0.9)


def _boundaries(axes: Sequence[Any], utt: Utterance) -> None:
    """Segment boundaries, one line collection per axis (none past MAX_SEGMENT_BOUNDARIES)."""
    if len(utt.labels) - 1 > MAX_SEGMENT_BOUNDARIES:
        return
    for ax in axes:
        ax.vlines(np.asarray(utt.starts)[1:], 0.0, 1.0, transform=ax.get_xaxis_transform(), colors="0.85",
                  lw=0.6, zorder=0)


def _label_and_title(axes: Sequence[Any], utts: Sequence[Utterance], titles: Sequence[str], width_in: float) -> None:
    """Segment labels, then the title above them, on each utterance's top panel; what a very long
    utterance leaves out is said in its title."""
    for ax, utt, title in zip(axes, utts, titles):
        n = len(utt.labels)
        left_out = [what for what, limit in (("boundaries", MAX_SEGMENT_BOUNDARIES + 1), ("labels", MAX_SEGMENT_LABELS))
                    if n > limit]
        lines = segment_labels(ax, utt.labels, utt.starts, utt.ends, width_in) if n <= MAX_SEGMENT_LABELS else 0
        if left_out:
            title += f"   ({n} segments: {' and '.join(left_out)} not drawn)"
        ax.set_title(title, fontsize=9, pad=6 + lines * (LABEL_FONT + 1))


def trajectory_figure(fit: ChannelFit, table: ParameterTable, utterances: Sequence[int]) -> Figure:
    """Measured vs modelled channel per utterance, the normalised dominances drawn underneath.

    The lower panel shows w_i(t) = S_i R_i D_i / Σ_j R_j D_j of every segment (F = Σ T_i w_i), as the
    paper's Figure 1 draws the dominance functions under the lower lip opening; each phoneme has one
    colour, named in the legend below. A sentence gets a row of its own, wide enough for its labels.
    """
    d = fit.problem.data
    utts = [d.utterances[u] for u in utterances]
    fig, axes, width_in = _panels(utts, 2, 5.2, (2.2, 1))
    colours = phoneme_colours([lab for u in utts for lab in u.labels])
    assert fit.fitted is not None
    titles = []
    for col, u in enumerate(utterances):
        utt = d.utterances[u]
        sl = d.utterance_samples(u)
        t = utt.times
        y = np.where(d.weights[sl] > 0, d.observed[sl], np.nan)
        top, bottom = axes[0, col], axes[1, col]
        top.plot(t, y, ".", ms=3, color="0.35", label="measured")
        top.plot(t, fit.fitted[sl], "-", color="C3", lw=1.6, label="model")
        rm = float(np.sqrt(np.nanmean((fit.fitted[sl] - y) ** 2)))
        _boundaries((top, bottom), utt)
        if len(utt.labels) <= MAX_SEGMENT_LABELS and len(utt.labels) * len(t) <= MAX_WEIGHT_VALUES:
            # (rows "p|s" of [model] speakers = "targets" are the table's p: the weights do not
            # depend on the targets, so the table's give this speaker's exactly)
            own = [lab if lab in table.values or "|" not in lab else lab.rpartition("|")[0] for lab in utt.labels]
            w = segment_weights(table, d.channel, own, utt.starts, utt.ends, t)
            for i, lab in enumerate(utt.labels):
                bottom.plot(t, w[i], lw=1.2, color=colours[lab])
                bottom.fill_between(t, 0, w[i], alpha=0.12, color=colours[lab])
        else:
            bottom.text(0.5, 0.5, f"weights not drawn: {len(utt.labels)} segments x {len(t)} samples",
                        transform=bottom.transAxes, ha="center", va="center", fontsize=8)
        top.set_xlim(float(t[0]), float(t[-1]))
        bottom.set_ylim(0, 1.05)
        bottom.set_xlabel("time (s)")
        top.set_ylabel(f"{d.channel} (mm)")
        bottom.set_ylabel("weight of target")
        if col == 0:
            top.legend(fontsize=7, loc="best")
        if _long(utts):  # one utterance per row: the time axis is labelled under the weights only
            top.tick_params(labelbottom=False)
        titles.append(f"{utterance_title(utt)}   RMSE {rm:.2f} mm")
    handles = [Line2D([], [], color=c, lw=2) for c in colours.values()]
    _bottom_legend(fig, handles, list(colours), "weight of each phoneme's target (lower panels)")
    _label_and_title(axes[0], utts, titles, width_in)
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


def residual_time_figure(result: FitResult, names: Sequence[str]) -> Figure | None:
    """Model − measured over time for the named utterances, every channel, segments labelled:
    where in a sentence the model misses, and in which channel."""
    first = next(iter(result.channels.values()))
    by_name = {u.name: u for u in first.problem.data.utterances}
    utts = [by_name[n] for n in names if n in by_name]
    if not utts:
        return None
    fig, axes, width_in = _panels(utts, 1, 2.6, (1,))
    lim = BAR_MM
    titles = []
    for col, utt in enumerate(utts):
        ax = axes[0, col]
        parts = []
        for k, (ch, fit) in enumerate(result.channels.items()):
            d = fit.problem.data
            u = next((i for i, x in enumerate(d.utterances) if x.name == utt.name), None)
            if u is None:
                continue
            sl = d.utterance_samples(u)
            r = fit.residuals()[sl]
            ax.plot(d.utterances[u].times, r, lw=0.9, color=f"C{k}", label=ch)
            if np.any(np.isfinite(r)):
                lim = max(lim, float(np.nanmax(np.abs(r))))
                parts.append(f"{ch} {float(np.sqrt(np.nanmean(r ** 2))):.2f}")
        _boundaries((ax,), utt)
        for b in (-BAR_MM, BAR_MM):
            ax.axhline(b, color="C3", ls="--", lw=0.7)
        ax.axhline(0, color="0.4", lw=0.6)
        ax.set_xlim(float(utt.times[0]), float(utt.times[-1]))
        ax.set_xlabel("time (s)")
        ax.set_ylabel("model − measured (mm)")
        titles.append(f"{utterance_title(utt)}   RMSE (mm): {', '.join(parts)}")
        if col == 0:
            ax.legend(fontsize=7, loc="upper right", ncol=len(result.channels))
    for col in range(len(utts)):
        axes[0, col].set_ylim(-1.1 * lim, 1.1 * lim)
    _label_and_title(axes[0], utts, titles, width_in)
    return fig


def phoneme_rmse(fit: ChannelFit) -> dict[str, tuple[float, int]]:
    """RMSE (mm) and sample count of the samples inside each phoneme's segments."""
    d = fit.problem.data
    r = fit.residuals()
    index = {p: k for k, p in enumerate(d.phonemes)}
    sse = np.zeros(len(d.phonemes))
    cnt = np.zeros(len(d.phonemes))
    for u, utt in enumerate(d.utterances):
        ru = r[d.utterance_samples(u)]
        starts, ends = np.asarray(utt.starts), np.asarray(utt.ends)
        seg = np.searchsorted(starts, utt.times, side="right") - 1
        inside = (seg >= 0) & (utt.times < ends[np.clip(seg, 0, None)]) & np.isfinite(ru)
        ph = np.array([index[lab] for lab in utt.labels], dtype=np.int64)[seg[inside]]
        sse += np.bincount(ph, weights=ru[inside] ** 2, minlength=len(sse))
        cnt += np.bincount(ph, minlength=len(cnt))
    return {p: (float(np.sqrt(sse[k] / cnt[k])), int(cnt[k])) for p, k in index.items() if cnt[k]}


def phoneme_rmse_figure(result: FitResult) -> Figure | None:
    """RMSE per phoneme (samples inside its segments), one bar per channel, the 0.3 mm bar dashed."""
    per = {ch: phoneme_rmse(fit) for ch, fit in result.channels.items()}
    phonemes = list(dict.fromkeys(p for ch in per for p in per[ch]))
    if not phonemes:
        return None
    nch = len(per)
    width = float(np.clip(0.9 + 0.22 * len(phonemes) * max(nch, 2), 6.0, 24.0))
    fig, ax = plt.subplots(figsize=(width, 3.2))
    bar = 0.8 / nch
    x = np.arange(len(phonemes))
    for k, (ch, values) in enumerate(per.items()):
        ax.bar(x - 0.4 + bar * (k + 0.5), [values.get(p, (np.nan, 0))[0] for p in phonemes], bar,
               color=f"C{k}", label=ch)
    ax.axhline(BAR_MM, color="C3", ls="--", lw=0.8)
    ax.set_xticks(x, phonemes, fontsize=8)
    ax.set_xlim(-0.6, len(phonemes) - 0.4)
    ax.set_ylabel("RMSE (mm)")
    ax.set_xlabel("phoneme (samples inside its segments)")
    ax.legend(fontsize=7, ncol=nch)
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
            ax.add_patch(Rectangle((j - 0.5, i - 0.5), 1, 1, fill=False, ec="red", lw=1.5))
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


def heldout_figure(result: FitResult) -> Figure | None:
    """Per channel: the fit's own RMSE and the held-out RMSE (every split's test samples pooled), as
    measured and with each utterance's offset removed, then each baseline's held-out RMSE on the
    same samples (``coartic.evaluation.baselines``, those the validation computed), the bar dashed."""
    from coartic.evaluation.baselines import BASELINES, TITLES

    scores = held_out(result)
    held = pooled(scores)
    chans = [ch for ch in result.channels if ch in held]
    if not chans:
        return None
    nan = (float("nan"), float("nan"), 0)
    bars = [("fit (in-sample)", [result.channels[ch].rmse for ch in chans], "0.6"),
            ("held out", [held[ch][0] for ch in chans], "C0"),
            ("held out, offset removed", [held[ch][1] for ch in chans], "C9")]
    for b, colour in zip(BASELINES, ("C1", "C2", "C4")):  # (C3, red, is the bar's)
        base = pooled(scores, b)
        if base:
            bars.append((f"baseline: {TITLES[b]}", [base.get(ch, nan)[0] for ch in chans], colour))
    fig, ax = plt.subplots(figsize=(4.0 + (0.25 + 0.2 * len(bars)) * len(chans), 2.8))  # legend on the right
    x = np.arange(len(chans))
    w = 0.8 / len(bars)
    for k, (label, values, colour) in enumerate(bars):
        ax.bar(x - 0.4 + w * (k + 0.5), values, w, color=colour, label=label)
    ax.axhline(BAR_MM, color="C3", ls="--", lw=0.8)
    ax.set_xticks(x, chans)
    ax.set_ylabel("RMSE (mm)")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    fig.tight_layout()
    return fig


def save(fig: Figure, path: Path) -> Path:
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
