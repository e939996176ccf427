"""`coartic inspect FILE`: what a recording holds (markers, rate, gaps, labels), and a plot of it."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import numpy as np
import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from coartic.io.errors import DataError
from coartic.io.gaps import DEFAULT_MAX_GAP, Gap, fill_gaps
from coartic.io.load import load_trial
from coartic.io.trial import Channels, Trial
from coartic.console import EXIT_NOTHING
from coartic.errors import UsageError


def inspect_command(
    file: Annotated[Path, typer.Argument(
        help="C3D, marker or EMA CSV/TSV, EMU bundle, MOCHA EST track, XRMB .txy or mview .mat file.")],
    labels: Annotated[Optional[Path], typer.Option(
        help="Label file: TextGrid, .lab, TIMIT .phn or TSV.")] = None,
    label_map: Annotated[Optional[str], typer.Option(
        help="Label map: a built-in name (model, german_sampa, english_arpabet, mocha, timit) or a "
             "TSV/JSON file.")] = None,
    role_map: Annotated[Optional[Path], typer.Option(
        help="JSON role map: which marker/sensor is NOSE, UL, LL, JAW...; EMA axes.")] = None,
    tier: Annotated[Optional[str], typer.Option(
        help="TextGrid tier (default: a phones tier, else the first interval tier).")] = None,
    units: Annotated[Optional[str], typer.Option(help="Override the file's length unit (mm, cm, m).")] = None,
    max_gap: Annotated[float, typer.Option(help="Longest gap (s) filled by interpolation.")] = DEFAULT_MAX_GAP,
    plot: Annotated[Optional[Path], typer.Option(help="Write a PNG of the channels here.")] = None,
    allow_truncated: Annotated[bool, typer.Option(
        help="Read a C3D that holds fewer frames than its header declares.")] = False,
) -> None:
    """Summarise a recording: markers, rate, frames, gaps per marker, labels, channels.

    Exits 2 when the file cannot be read, 1 when no channel can be computed from it."""
    console = Console()
    if plot is not None:  # checked first: the summary should not be lost to a typo in the plot's path
        from coartic.outputs import check_output_file

        check_output_file(plot, "--plot", file.stem + ".png")
    trial = load_trial(file, labels=labels, label_map=label_map, role_map=role_map, tier=tier,
                       units=units, allow_truncated=allow_truncated)
    _, gaps = fill_gaps(trial.markers, trial.marker_names, trial.rate, trial.start_time, max_gap)
    channels: Channels | None = None
    channel_error = ""
    try:
        channels = trial.channels(max_gap=max_gap)
    except DataError as e:
        channel_error = str(e)
    except ImportError as e:  # the Rust core is not built
        channel_error = f"channels need the compiled core: {e}"
    _summary(console, trial)
    _markers(console, trial, gaps)
    if trial.segments is not None:
        _labels(console, trial)
    if channels is not None and len(channels):
        _channels(console, channels)
    else:
        console.print(f"[yellow]no channels:[/] {escape(channel_error or 'none can be computed')}")
        for name, why in (channels.unavailable.items() if channels is not None else ()):
            console.print(f"  {name} not available: {escape(why)}")
    if plot is not None:
        try:
            plot_trial(trial, channels, plot)
        except OSError as e:
            raise UsageError(f"--plot {plot}: cannot write it: {e.strerror or e}") from None
        console.print(f"plot written to {plot}")
    if channels is None or not len(channels):
        raise typer.Exit(EXIT_NOTHING)  # scripts must see that nothing usable came out of the file


def _summary(console: Console, trial: Trial) -> None:
    console.print(f"[bold]{trial.source}[/]  ({trial.kind})")
    console.print(f"  {len(trial.marker_names)} markers, {trial.n_frames} frames at "
                  f"{trial.rate:g} Hz = {trial.duration:.3f} s from {trial.start_time:g} s, "
                  f"units {trial.units}")
    for note in trial.meta.get("notes", []):
        console.print(f"  note: {note}")
    if trial.roles.roles:
        console.print("  roles: " + ", ".join(f"{r}={n}" for r, n in trial.roles.roles.items()))


def _markers(console: Console, trial: Trial, gaps: list[Gap]) -> None:
    table = Table(title="markers")
    for col in ("marker", "missing %", "gaps", "filled", "left missing", "longest gap"):
        table.add_column(col, justify="left" if col == "marker" else "right")
    valid = trial.valid
    for j, name in enumerate(trial.marker_names):
        mine = [g for g in gaps if g.marker == name]
        longest = max((g.frames / trial.rate for g in mine), default=0.0)
        table.add_row(name, f"{100 * (1 - valid[:, j].mean()):.1f}", str(len(mine)),
                      str(sum(g.filled for g in mine)), str(sum(not g.filled for g in mine)),
                      f"{1000 * longest:.0f} ms" if mine else "-")
    console.print(table)
    open_gaps = [g for g in gaps if not g.filled]
    for g in open_gaps[:20]:
        console.print(f"  gap {g}")
    if len(open_gaps) > 20:
        console.print(f"  ... and {len(open_gaps) - 20} more gaps left missing")


def _labels(console: Console, trial: Trial) -> None:
    segs = trial.segments
    assert segs is not None
    raw = trial.meta.get("raw_labels", segs.labels)
    table = Table(title=f"labels ({len(segs)} segments, map: {trial.meta.get('label_map')})")
    for col in ("#", "start", "end", "label", "phoneme"):
        table.add_column(col, justify="right" if col in ("#", "start", "end") else "left")
    for i, (r, p, s, e) in enumerate(zip(raw, segs.labels, segs.starts, segs.ends), start=1):
        table.add_row(str(i), f"{s:.3f}", f"{e:.3f}", r, p)
    console.print(table)


def _channels(console: Console, ch: Channels) -> None:
    table = Table(title="channels (mm)")
    for col in ("channel", "min", "max", "mean", "valid %"):
        table.add_column(col, justify="left" if col == "channel" else "right")
    for name, v in ch.items():
        ok = ch.valid[name]
        if ok.any():
            table.add_row(name, f"{np.min(v[ok]):.2f}", f"{np.max(v[ok]):.2f}",
                          f"{np.mean(v[ok]):.2f}", f"{100 * ok.mean():.1f}")
        else:
            table.add_row(name, "-", "-", "-", "0.0")
    console.print(table)
    for name, why in ch.unavailable.items():
        console.print(f"  {name} not available: {why}")


def plot_trial(trial: Trial, channels: Channels | None, out: Path) -> None:
    """One panel per channel (or per marker coordinate when there are no channels), labels on top."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = trial.times
    if channels is not None and len(channels):
        series = [(name, v) for name, v in channels.items()]
    else:
        series = [(f"{name} ({axis})", trial.markers[:, j, k])
                  for j, name in enumerate(trial.marker_names[:4]) for k, axis in enumerate("xyz")]
    fig, axes = plt.subplots(len(series), 1, sharex=True, figsize=(10, 1.4 * len(series) + 1),
                             squeeze=False)
    for ax, (name, v) in zip(axes[:, 0], series):
        ax.plot(t, v, lw=1.0, color="C0")
        ax.set_ylabel(f"{name}\n(mm)", rotation=0, ha="right", va="center", fontsize=8)
        ax.grid(alpha=0.3)
    note = ""
    if trial.segments is not None:
        from coartic.runtime.preview import mark_segments  # the one bounded way to mark segments

        note = mark_segments(list(axes[:, 0]), trial.segments, color="0.7", fontsize=7)
    axes[-1, 0].set_xlabel("time (s)")
    fig.suptitle(" ".join(part for part in (trial.source.name if trial.source else "trial", note) if part), y=1.0)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
