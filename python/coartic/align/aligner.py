"""`coartic align` as a library: a recording and its transcript (or none, in English) → an
`Alignment`, written as a TextGrid in the Montreal Forced Aligner's layout (a words tier, a phones
tier) with a third tier of the model's phonemes, which `coartic animate` reads."""

from __future__ import annotations

import warnings
from os import PathLike
from pathlib import Path
from typing import TYPE_CHECKING, Any

from coartic.align.audio import MAX_DURATION, Recording, is_pcm_wav, read_recording, write_pcm16
from coartic.align.alignment import Alignment, Progress, align_by_synthesis
from coartic.align.errors import AlignError, AlignWarning
from coartic.align.synthesis import ENGINES, default_engine
from coartic.outputs import atomic_write_text

if TYPE_CHECKING:
    from coartic.runtime.pipeline import RuntimeOutput
    from coartic.table import ParameterTable

ALL_ENGINES = (*ENGINES, "sphinx")
WORD_TIERS = ("words", "word", "Word", "ORT", "ort")
PHONEMES_TIER = "phonemes"  # the model's phonemes, the tier `coartic animate` reads from an alignment


def read_transcript(path: str | PathLike[str]) -> str:
    """The words of a transcript file: plain text, or a TextGrid's words tier (its non-empty intervals)."""
    from coartic.io.errors import DataError
    from coartic.io.labels import read_labels
    from coartic.textfile import TextDecodeError, read_text

    p = Path(path)
    try:
        text = read_text(p)
    except FileNotFoundError:
        raise AlignError(f"{p}: no such transcript file") from None
    except (OSError, TextDecodeError) as err:
        raise AlignError(f"{p}: cannot read the transcript ({err})") from None
    if "TextGrid" not in text[:200]:
        return " ".join(text.split())
    last: DataError | None = None
    for tier in WORD_TIERS:
        try:
            seg = read_labels(p, tier=tier)
        except DataError as err:
            last = err
            continue
        words = [w.strip() for w in seg.labels if w.strip() and w.strip() not in ("<sil>", "sil", "sp", "<p:>")]
        if not words:
            raise AlignError(f"{p}: tier {tier!r} holds no words")
        return " ".join(words)
    raise AlignError(f"{p}: no words tier (named one of {', '.join(WORD_TIERS)}): {last}")


def align_recording(
    wav: str | PathLike[str],
    text: str | None,
    lang: str = "it",
    engine: str | None = None,
    *,
    max_duration: float = MAX_DURATION,
    progress: Progress | None = None,
) -> Alignment:
    """Align `text` to the recording `wav` (module docstring). `engine`: festival or espeak
    (alignment by synthesis) or sphinx (PocketSphinx, English only); default: sphinx for English,
    else `default_engine(lang)`. Without `text` (English only) the phones are recognised, not aligned:
    less accurate, and said so in the alignment's warnings. Doubts (a transcript the recording seems
    not to say, speech left after it) are AlignWarnings, also kept in `Alignment.warnings`."""
    if engine is not None and engine not in ALL_ENGINES:
        raise AlignError(f"--engine {engine!r} is not an aligner (known: {', '.join(ALL_ENGINES)})")
    recording = read_recording(wav, max_duration=max_duration)
    if text is not None and not text.strip():
        raise AlignError("the transcript is empty: give the words the recording says (--text or --transcript)")
    english = lang.split("-")[0] == "en"
    if text is None:
        if not english or engine not in (None, "sphinx"):
            raise AlignError(f"{wav}: no transcript: recognising phones without one is done for English only "
                             "(--lang en, PocketSphinx); give the words with --text or --transcript")
        from coartic.align.sphinx import recognise_phones

        alignment = recognise_phones(recording, progress=progress)
    elif engine == "sphinx" or (engine is None and english and default_english() == "sphinx"):
        if not english:
            raise AlignError(f"--engine sphinx aligns English only (its en-us model), not {lang!r}; "
                             f"use --engine {default_engine(lang)}")
        alignment = align_english(recording, text, progress)
    else:
        alignment = align_by_synthesis(recording, text, lang, engine, progress=progress)
    for message in alignment.warnings:
        warnings.warn(message, AlignWarning, stacklevel=2)
    return alignment


def align_english(recording: Recording, text: str, progress: Progress | None = None) -> Alignment:
    """PocketSphinx's forced alignment, with the confidence (and the warnings) of an alignment by
    synthesis with Festival, which is also the answer, said in a warning, where PocketSphinx fails
    (a word its dictionary lacks, or a path its beams lose)."""
    from coartic.align.sphinx import align_sphinx

    check = align_by_synthesis(recording, text, "en", "festival")
    try:
        alignment = align_sphinx(recording, text, progress=progress, parts=check.parts)
    except AlignError as err:
        check.warnings.insert(0, f"{err}: aligned by synthesis with Festival instead (less accurate on English: "
                                 "docs/ALIGN.md)")
        if progress is not None:
            progress(1, 1)
        return check
    alignment.confidence = check.confidence
    alignment.warnings.extend(w for w in check.warnings if "poorly" in w)
    return alignment


def default_english() -> str:
    """The English aligner used when none is named: PocketSphinx, more accurate than Festival and DTW on
    English (bench/align_accuracy.py; docs/ALIGN.md)."""
    return "sphinx"


def _quote(label: str) -> str:
    return '"' + label.replace('"', '""') + '"'


def textgrid_text(alignment: Alignment) -> str:
    """The alignment as a Praat TextGrid (long text format): tiers words, phones, phonemes."""
    tiers: list[tuple[str, list[tuple[str, float, float]]]] = [
        ("words", alignment.word_intervals()),
        ("phones", [(p, float(s), float(e)) for p, s, e in zip(alignment.phones, alignment.starts, alignment.ends)]),
        (PHONEMES_TIER, [(p, float(s), float(e)) for p, s, e in zip(alignment.phonemes, alignment.starts, alignment.ends)]),
    ]
    end = alignment.duration
    lines = ['File type = "ooTextFile"', 'Object class = "TextGrid"', "", "xmin = 0", f"xmax = {end!r}",
             "tiers? <exists>", f"size = {len(tiers)}", "item []:"]
    for t, (name, intervals) in enumerate(tiers, start=1):
        lines += [f"    item [{t}]:", '        class = "IntervalTier"', f"        name = {_quote(name)}",
                  "        xmin = 0", f"        xmax = {end!r}", f"        intervals: size = {len(intervals)}"]
        for k, (label, s, e) in enumerate(intervals, start=1):
            lines += [f"        intervals [{k}]:", f"            xmin = {s!r}", f"            xmax = {e!r}",
                      f"            text = {_quote(label)}"]
    return "\n".join(lines) + "\n"


def write_alignment(alignment: Alignment, out: Path, name: str) -> dict[str, Path]:
    """NAME.TextGrid (words, phones, phonemes) and NAME.align.txt (how it was aligned, its warnings)."""
    grid = out / f"{name}.TextGrid"
    atomic_write_text(grid, textgrid_text(alignment))
    report = out / f"{name}.align.txt"
    confidence = "" if alignment.confidence is None else f"warp distance ratio: {alignment.confidence:.3f}\n"
    atomic_write_text(report, f"method: {alignment.method}\n{confidence}phones: {len(alignment.phones)}\n"
                      f"words: {len(alignment.words)}\nduration: {alignment.duration:.3f} s\n"
                      + "".join(f"warning: {w}\n" for w in alignment.warnings))
    return {"textgrid": grid, "alignment report": report}


def is_wav(path: str | PathLike[str]) -> bool:
    """Whether `path` is a WAV file (RIFF/RIFX/RF64 header), to tell a recording from a label file."""
    try:
        with open(path, "rb") as f:
            head = f.read(12)
    except OSError:
        return False
    return head[:4] in (b"RIFF", b"RIFX", b"RF64") and head[8:12] == b"WAVE"


def animate_recording(wav: str | PathLike[str], text: str | None, table: ParameterTable, out: str | PathLike[str], *,
                      lang: str = "it", engine: str | None = None, max_duration: float = MAX_DURATION,
                      align_progress: Progress | None = None, name: str | None = None,
                      **animate: Any) -> RuntimeOutput:
    """Align the recording `wav` to `text` (`align_recording`), write the alignment into `out`
    (NAME.TextGrid, NAME.align.txt) and animate its phonemes with the recording as the sound:
    everything `coartic animate` writes for a label file and its --audio. `animate`: the other
    keyword arguments of `coartic.runtime.pipeline.animate_file`."""
    from coartic.io.labelmap import LabelMap
    from coartic.runtime.pipeline import _name_from, animate_file, check_name

    alignment = align_recording(wav, text, lang, engine, max_duration=max_duration, progress=align_progress)
    stem = check_name(name) if name is not None else _name_from(Path(wav).stem)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files = write_alignment(alignment, out, stem)
    # a recording the runtime's WAV copy cannot take (float, 24-bit extensible) is the sound as 16-bit PCM
    sound = Path(wav) if is_pcm_wav(wav) else write_pcm16(wav, out / f"{stem}.wav")
    # the phonemes tier holds model phonemes already, and phonemes outside the Italian set (h) are kept
    # for the phone map's fallbacks
    result = animate_file(files["textgrid"], table, out, tier=PHONEMES_TIER, label_map=LabelMap.from_dict({"*": "="}),
                          phone_map=alignment.phone_map, audio=sound, name=stem, **animate)
    result.files = {**files, **result.files}
    return result
