"""`coartic align`: a recording and its transcript → a TextGrid (words, phones, phonemes)."""

from __future__ import annotations

import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

from coartic.align.alignment import Progress as PartProgress
from coartic.align.audio import MAX_DURATION
from coartic.console import LineProgress, positive_finite, print_warning

_err = Console(stderr=True)
_out = Console()

TextOpt = Annotated[str | None, typer.Option("--text", help="What the recording says (its transcript).")]
TranscriptOpt = Annotated[Path | None, typer.Option("--transcript", help="The transcript as a file: plain text, or a TextGrid with a words tier.")]
LangOpt = Annotated[str, typer.Option("--lang", help="Language of the recording: it, en, de, or any espeak-ng voice (fr, es, ...).")]
EngineOpt = Annotated[str | None, typer.Option("--engine", help="Aligner: sphinx (PocketSphinx, English; the default for en), festival (alignment by synthesis with Festival; it, en; the default for it), espeak (alignment by synthesis with espeak-ng; the default for other languages).")]
MaxDurationOpt = Annotated[float, typer.Option("--max-duration", callback=positive_finite,
                                               help="Refuse recordings longer than this (s).")]


def transcript_text(text: str | None, transcript: Path | None) -> str | None:
    """The words from --text or --transcript (one of them, or none)."""
    from coartic.align.aligner import read_transcript
    from coartic.align.errors import AlignError

    if text is not None and transcript is not None:
        raise AlignError("give the transcript once: --text or --transcript, not both")
    return read_transcript(transcript) if transcript is not None else text


@contextmanager
def shown_warnings() -> Iterator[None]:
    """AlignWarnings (a doubtful alignment) printed as `warning:` lines on stderr."""
    from coartic.align.errors import AlignWarning

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", AlignWarning)
        try:
            yield
        finally:
            for w in caught:
                if issubclass(w.category, AlignWarning):
                    print_warning(_err, str(w.message))
                else:
                    warnings.showwarning(w.message, w.category, w.filename, w.lineno)


def part_progress(progress: Progress, what: str) -> PartProgress:
    """A progress task counting the parts of the transcript aligned (long recordings have several)."""
    task = progress.add_task(what, total=None, unit="parts")

    def advance(done: int, total: int) -> None:
        progress.update(task, completed=done, total=total)

    return advance


def align_command(
    recording: Annotated[Path, typer.Argument(help="The recording (WAV).")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Output directory (created if needed).")],
    text: TextOpt = None,
    transcript: TranscriptOpt = None,
    lang: LangOpt = "it",
    engine: EngineOpt = None,
    name: Annotated[str | None, typer.Option("--name", help="Stem of the files written (default: the recording's).")] = None,
    max_duration: MaxDurationOpt = MAX_DURATION,
    force: Annotated[bool, typer.Option("--force", help="Replace --out even if it holds another run's output.")] = False,
) -> None:
    """Align a recording to its transcript: NAME.TextGrid (tiers words, phones and the model's phonemes, which
    `coartic animate` reads) and NAME.align.txt (method, confidence, warnings).

    Without a transcript (English only) the phones are recognised, which is less accurate."""
    from coartic.align.aligner import align_recording, write_alignment
    from coartic.outputs import OutputDir
    from coartic.runtime.pipeline import _name_from, check_name

    words = transcript_text(text, transcript)
    stem = check_name(name) if name is not None else _name_from(recording.stem)
    identity = {"recording": str(recording.resolve()), "lang": lang}
    with shown_warnings(), OutputDir(out, "align", identity, force=force,
                                     protect=[recording, *([transcript] if transcript else [])]) as staging, \
            LineProgress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                         TimeRemainingColumn(), console=_err) as progress:
        alignment = align_recording(recording, words, lang, engine, max_duration=max_duration,
                                    progress=part_progress(progress, "aligning"))
        files = write_alignment(alignment, staging, stem)
    _out.print(f"{alignment.method}: {len(alignment.phones)} phones, {len(alignment.words)} words", highlight=False,
               soft_wrap=True)
    for what, path in files.items():
        _out.print(f"{what}: {out / path.name}", highlight=False, soft_wrap=True)
