"""``coartic score TABLE RECORDING... --labels L...``: how well a fitted table predicts recordings
it was not fitted on (RMSE per channel, utterance and phoneme, as measured and without offsets)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from coartic.console import print_table
from coartic.fit.result import BAR_MM


def score_command(
    table: Path = typer.Argument(..., help="fitted table (table.json of coartic fit)"),
    recordings: list[Path] = typer.Argument(..., help="recordings to predict (C3D, marker or EMA CSV, EMU bundle)"),
    labels: Optional[list[Path]] = typer.Option(None, "--labels", "-l",
                                                help="label file of each recording, in the same order (repeat)"),
    label_map: Optional[str] = typer.Option(None, "--label-map", help="corpus labels -> model phonemes (built-in "
                                            "name or file); default: the map the table records"),
    channels: Optional[str] = typer.Option(None, help="comma-separated channels (default: the table's)"),
    role_map: Optional[Path] = typer.Option(None, "--role-map", help="which sensor/marker plays which role, and the "
                                            "EMA axes (JSON file); default: the role map the table records"),
    strict: bool = typer.Option(False, "--strict", help="refuse phonemes the table lacks instead of scoring them "
                                "as their phonetic class's fallback (the label map's, e.g. labelmaps/fallbacks.tsv)"),
    train: Optional[Path] = typer.Option(None, "--train", help="fit spec of the table's training data, for the "
                                         "baselines (default: the spec the table records, if it exists)"),
    speaker: Optional[str] = typer.Option(None, "--speaker", help="predict as this speaker of the table (a table "
                                          "fitted with \\[model] speakers): its offset and scale, or its own targets"),
    out: Optional[Path] = typer.Option(None, "--out", "-o", help="write CSVs, score.txt and figures here"),
    force: bool = typer.Option(False, "--force", help="replace --out even if it holds another run's output"),
) -> None:
    """Predict recordings the fit did not see and report the RMSE (also after removing a
    per-utterance offset, and after calibrating the speaker's offset and scale on these recordings)."""
    from coartic.evaluation.score import score_recordings

    console = Console()
    chans = [c.strip() for c in channels.split(",") if c.strip()] if channels else None
    score = score_recordings(table, recordings, labels or None, label_map=label_map, channels=chans,
                             speaker=speaker, role_map=role_map, strict=strict, train=train)
    if out is not None:
        from coartic.outputs import OutputDir

        identity = {"table": str(table.resolve()), "recordings": ",".join(str(r) for r in recordings),
                    **({"speaker": speaker} if speaker is not None else {})}
        with OutputDir(out, "score", identity, force=force, protect=[table, *recordings, *(labels or [])]) as d:
            score.save(d)
    print_table(console, score_table(score), keys=2)
    for note in score.notes:
        console.print(f"note: {escape(note)}", soft_wrap=True, highlight=False)
    for flag in score.flags():
        console.print(f"[bold red]WORSE THAN THE STEP MODEL[/bold red] {escape(flag)}", soft_wrap=True, highlight=False)
    if out is not None:
        console.print(escape(f"written: {out}/score_*.csv, score.txt, summary.json, figures/"), soft_wrap=True,
                      highlight=False)


def score_table(score: object) -> Table:
    from coartic.evaluation.score import Score

    assert isinstance(score, Score)
    who = f" as speaker {score.speaker}" if score.speaker is not None else ""
    t = Table(title=f"RMSE (mm){who} on {len(score.utterances)} recording(s) the fit did not see — bar {BAR_MM} mm",
              caption=score.caption())
    for c in ("channel", "model", "as measured", "offset removed", "speech only", "speaker-calibrated",
              "worst utterance", "worst phoneme", "samples"):
        t.add_column(c, justify="left" if c in ("channel", "model") else "right")
    utt = score.utterance_rows()
    ph = score.phoneme_rows()
    for r in score.channel_rows():
        ch = r["channel"]
        wu = max((x for x in utt if x["channel"] == ch), key=lambda x: x["rmse_mm"])
        wp = next((x for x in ph if x["channel"] == ch), None)  # sorted worst first
        t.add_row(ch, "table", f"{r['rmse_mm']:.3f}", f"{r['rmse_offset_removed_mm']:.3f}", _speech(r),
                  f"{r['rmse_calibrated_mm']:.3f}", f"{wu['rmse_mm']:.3f} ({escape(wu['utterance'])})",
                  f"{wp['rmse_mm']:.3f} ({escape(wp['phoneme'])})" if wp else "–", str(r["samples"]))
        for b in (x for x in score.baseline_rows() if x["channel"] == ch and x["model"] != "table"):
            t.add_row(ch, f"[dim]{b['model']}[/dim]", f"{b['rmse_mm']:.3f}", f"{b['rmse_offset_removed_mm']:.3f}",
                      _speech(b), f"{b['rmse_calibrated_mm']:.3f}", "–", "–", str(b["samples"]))
    return t


def _speech(row: dict[str, object]) -> str:
    """The speech-only RMSE (pauses left out) as measured / offset removed."""
    return f"{row['rmse_speech_mm']:.3f} / {row['rmse_speech_offset_removed_mm']:.3f}"
