"""Italian (or English) text through the Festival speech synthesiser: a WAV and its Segment relation.

Festival is run as a program (`festival -b script.scm`) with a generated Scheme script, because
that is how the Debian package is used everywhere; its Italian phone set is mapped to the model's
phonemes by phones_italian.tsv, its English (radio, ARPAbet) phone set by phones_english.tsv.
"""

from __future__ import annotations

import csv
import math
import os
import re
import shutil
import subprocess
import tempfile
import time
import unicodedata
import wave
from collections.abc import Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING

from coartic.runtime.errors import FestivalError, PhoneMapError

if TYPE_CHECKING:  # NumPy is imported when a result is read: `coartic speak` starts Festival before it
    import numpy as np
    from numpy.typing import NDArray

DEFAULT_VOICE = "pc_diphone"
# Per language: the Festival voice used when none is named, the phone map of its phone set, and the
# Debian packages that install it.
LANGUAGES: dict[str, tuple[str, str, str]] = {
    "it": ("pc_diphone", "phones_italian.tsv", "festival and festvox-italp16k"),
    "en": ("kal_diphone", "phones_english.tsv", "festival and festvox-kallpc16k"),
}
_VOICE_NAME = re.compile(r"^[A-Za-z0-9_]+$")
# Typographic punctuation an Italian text editor produces; the Italian voice reads ISO-8859-1 only.
_TYPOGRAPHIC = str.maketrans({"\u2019": "'", "\u2018": "'", "\u201c": '"', "\u201d": '"',
                              "\u00ab": '"', "\u00bb": '"', "\u2013": "-", "\u2014": "-", "\u2026": "..."})
_INSTALL_HINT = "install the Debian packages festival and festvox-italp16k (Italian), festvox-kallpc16k (English)"


def language(lang: str) -> tuple[str, str, str]:
    """(default voice, phone map file, Debian packages) of a language code, or an error listing the known ones."""
    if lang not in LANGUAGES:
        raise FestivalError(f"language {lang!r} is not one coartic can speak (known: {', '.join(LANGUAGES)})")
    return LANGUAGES[lang]


@dataclass(frozen=True)
class PhoneMap:
    """Festival phone → model phoneme, with fallback phonemes for tables that lack the phoneme."""

    phonemes: dict[str, str]
    fallbacks: dict[str, tuple[str, ...]]
    source: str

    @classmethod
    def load(cls, path: str | Path | None = None, lang: str = "it") -> PhoneMap:
        """Read a phone map TSV (`festival, phoneme, fallbacks, why`); default: the one of `lang`
        (phones_italian.tsv, or phones_english.tsv for "en")."""
        if path is None:
            name = language(lang)[1]
            ref = resources.files("coartic.runtime").joinpath(name)
            text, source = ref.read_text(encoding="utf-8"), name
        else:
            try:
                text, source = Path(path).read_text(encoding="utf-8"), str(path)
            except OSError as err:
                raise PhoneMapError(f"{path}: cannot read the phone map ({err.strerror})") from None
        rows = list(csv.reader(text.splitlines(), delimiter="\t"))
        # the first column is a TTS's phone: "festival" in Festival's maps, "phone" in phones_ipa.tsv (espeak-ng)
        if not rows or [c.strip() for c in rows[0][:3]] not in (["festival", "phoneme", "fallbacks"],
                                                               ["phone", "phoneme", "fallbacks"]):
            raise PhoneMapError(f"{source}, line 1: header must start with festival<TAB>phoneme<TAB>fallbacks "
                                "(or phone<TAB>phoneme<TAB>fallbacks)")
        phonemes: dict[str, str] = {}
        fallbacks: dict[str, tuple[str, ...]] = {}
        for lineno, row in enumerate(rows[1:], start=2):
            if not any(c.strip() for c in row):
                continue
            if len(row) < 2 or not row[0].strip() or not row[1].strip():
                raise PhoneMapError(f"{source}, line {lineno}: need a Festival phone and a model phoneme, got {row!r}")
            phone, phoneme = row[0].strip(), row[1].strip()
            if phone in phonemes:
                raise PhoneMapError(f"{source}, line {lineno}: Festival phone {phone!r} is mapped twice")
            phonemes[phone] = phoneme
            extra = row[2].strip() if len(row) > 2 else ""
            listed = tuple(p.strip() for p in extra.split(",") if p.strip())
            if listed and fallbacks.get(phoneme) and fallbacks[phoneme] != listed:
                raise PhoneMapError(
                    f"{source}, line {lineno}: fallbacks {','.join(listed)} for phoneme {phoneme!r} differ "
                    f"from the {','.join(fallbacks[phoneme])} given on an earlier line"
                )
            if listed:
                fallbacks[phoneme] = listed
        return cls(phonemes=phonemes, fallbacks=fallbacks, source=source)

    def to_phonemes(self, phones: Sequence[str]) -> list[str]:
        """Model phonemes of Festival phones; an unmapped phone is an error that names it."""
        out = []
        for i, phone in enumerate(phones):
            if phone not in self.phonemes:
                raise PhoneMapError(
                    f"Festival phone {phone!r} (segment {i + 1}) is not in {self.source}; "
                    f"known phones: {' '.join(sorted(self.phonemes))}"
                )
            out.append(self.phonemes[phone])
        return out


@dataclass(frozen=True)
class FestivalUtterance:
    """What Festival said: its phones with acoustic times (s) and the WAV it wrote."""

    text: str
    phones: tuple[str, ...]
    starts: NDArray[np.float64]
    ends: NDArray[np.float64]
    wav: Path
    duration: float
    dropped: tuple[str, ...] = ()
    # per phone: the word it belongs to (Festival's lower-cased token, "" for a pause) and that word's
    # number in the utterance (-1 for a pause), so that two equal words in a row stay two
    words: tuple[str, ...] = ()
    word_ids: tuple[int, ...] = ()


def prepare_text(text: str) -> str:
    """The text as the Italian voice can read it (ISO-8859-1), or an error naming what is wrong."""
    cleaned = " ".join(text.translate(_TYPOGRAPHIC).split())
    if not cleaned:
        raise FestivalError("empty text: there is nothing to say")
    for i, ch in enumerate(cleaned):
        if ord(ch) > 0xFF:
            raise FestivalError(
                f"character {ch!r} (U+{ord(ch):04X}) at position {i} of the text cannot be read by "
                "Festival's voices (ISO-8859-1 only)"
            )
    return cleaned


def _scheme_string(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _script(text: str, voice: str, stretch: float, segs: Path, wav: Path) -> str:
    return "\n".join([
        f"(voice_{voice})",
        f"(Parameter.set 'Duration_Stretch {stretch!r})",
        f"(set! utt (Utterance Text {_scheme_string(text)}))",
        "(utt.synth utt)",
        f"(set! fd (fopen {_scheme_string(str(segs))} \"w\"))",
        '(mapcar (lambda (s) (format fd "%s\\t%f\\t%s\\t%s\\n" (item.name s) (item.feat s "end")'
        ' (item.feat s "R:SylStructure.parent.parent.name") (item.feat s "R:SylStructure.parent.parent.id")))'
        " (utt.relation.items utt 'Segment))",
        "(fclose fd)",
        f"(utt.save.wave utt {_scheme_string(str(wav))} 'riff)",
        "",
    ])


def festival_program(festival: str = "festival") -> str:
    """Absolute path of the Festival program, or a FestivalError saying it is not installed."""
    found = shutil.which(festival)
    if found is None:
        raise FestivalError(f"Festival program {festival!r} not found on PATH ({_INSTALL_HINT})")
    return found


def wav_duration(path: Path) -> float:
    try:
        with wave.open(str(path), "rb") as w:
            return w.getnframes() / float(w.getframerate())
    except (OSError, wave.Error, EOFError) as err:
        raise FestivalError(f"{path}: Festival's WAV cannot be read ({err})") from None


def _parse_segments(path: Path) -> tuple[list[str], list[float], list[str], list[int]]:
    """Phones, end times and (from the third and fourth columns) each phone's word and word number."""
    phones: list[str] = []
    ends: list[float] = []
    words: list[str] = []
    word_ids: list[int] = []
    for lineno, line in enumerate(path.read_text(encoding="latin-1").splitlines(), start=1):
        if not line.strip():
            continue
        parts = line.split("\t")
        try:
            end = float(parts[1])
        except (IndexError, ValueError):
            raise FestivalError(f"Festival's segment list {path}, line {lineno}: expected 'phone<TAB>end', got {line!r}") from None
        phones.append(parts[0])
        ends.append(end)
        # a pause has no word: Festival says 0 for the feature of a missing item; ids are "_<n>"
        wid = parts[3].strip() if len(parts) > 3 else "0"
        in_word = wid.startswith("_") and wid[1:].isdigit()
        words.append(parts[2].strip() if in_word else "")
        word_ids.append(int(wid[1:]) if in_word else -1)
    return phones, ends, words, word_ids


# Festival's Scheme heap, in cells: its default, 10 million (320 MB), costs 0.2 s of page faults at
# every start, longer than a short sentence takes to synthesise. The voice loads in under 150 000
# cells; 1 million speaks a 4000-character paragraph to the same bytes as the default (and 17 000
# characters with no error), and the heap grows with the text beyond that.
FESTIVAL_HEAP_CELLS = 1_000_000
FESTIVAL_HEAP_CELLS_PER_CHAR = 100


def festival_heap(text: str) -> int:
    """The heap (cells) Festival is started with for `text` (FESTIVAL_HEAP_CELLS)."""
    return FESTIVAL_HEAP_CELLS + FESTIVAL_HEAP_CELLS_PER_CHAR * len(text)


def check_text(text: str) -> str:
    """Text Festival can be given whole: a NUL ends a C string (Festival said only what came before
    it), and other control characters are not speech; tabs and line breaks are spaces."""
    for i, ch in enumerate(text):
        if unicodedata.category(ch) == "Cc" and ch not in "\t\n\r":
            raise FestivalError(f"the text to speak holds the control character {ch!r} at position {i + 1}: "
                                "Festival would cut or garble it; remove it")
    return text


class Synthesis:
    """Festival started on a text (`start_synthesis`) and running while the caller goes on: `coartic
    speak` starts it before importing the model and loading the table. `result` waits for it; leaving
    the `with` block stops it if it still runs and removes its files."""

    def __init__(self, text: str, voice: str, packages: str, program: str, stretch: float, timeout: float) -> None:
        self.text, self.voice, self._packages, self._timeout = text, voice, packages, timeout
        self._tmp = tempfile.TemporaryDirectory(prefix="coartic-festival-")
        tmp = Path(self._tmp.name)
        self._segs, self._wav, self._stderr = tmp / "segments.tsv", tmp / "speech.wav", tmp / "stderr.txt"
        script = tmp / "say.scm"
        script.write_bytes(_script(text, voice, stretch, self._segs, self._wav).encode("latin-1"))
        self._started = time.monotonic()
        # stderr to a file, not a pipe: nothing reads it while Festival runs
        with open(self._stderr, "wb") as err:
            try:
                self._proc: subprocess.Popen[bytes] | None = subprocess.Popen(
                    [program, "--heap", str(festival_heap(text)), "-b", str(script)], stdin=subprocess.DEVNULL,
                    stdout=subprocess.DEVNULL, stderr=err, cwd=tmp, env={**os.environ, "LC_ALL": "C"},
                )
            except OSError as e:
                self._tmp.cleanup()
                raise FestivalError(f"Festival ({program}) could not be started: {e.strerror}") from None

    def __enter__(self) -> Synthesis:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if self._proc is not None and self._proc.poll() is None:
            self._proc.kill()
            self._proc.wait()
        self._proc = None
        self._tmp.cleanup()

    def result(self, wav_path: str | Path) -> FestivalUtterance:
        """Wait for Festival, copy its WAV to `wav_path` and return its segments (zero-length ones
        dropped, their names kept in `dropped`)."""
        import numpy as np

        if self._proc is None:
            raise FestivalError("this Festival run was closed before its result was taken")
        cleaned = self.text
        try:
            code = self._proc.wait(timeout=max(self._timeout - (time.monotonic() - self._started), 0.0))
        except subprocess.TimeoutExpired:
            self.close()
            raise FestivalError(f"Festival did not finish within {self._timeout:g} s on {cleaned!r}") from None
        # Festival always complains that `festival -b` left its own script open: not news.
        stderr = "\n".join(ln for ln in self._stderr.read_bytes().decode("latin-1", "replace").strip().splitlines()
                           if not ln.startswith("closing a file left open"))
        if code != 0 or not self._segs.exists() or not self._wav.exists():
            detail = stderr.splitlines()[-3:] if stderr else ["(no message)"]
            hint = (f"; is voice {self.voice!r} installed (the Debian packages {self._packages})?"
                    if "voice_" in stderr else "")
            if "ran out of storage" in stderr:
                hint = f"; Festival's heap of {festival_heap(cleaned)} cells was too small for this text"
            self.close()
            raise FestivalError(f"Festival failed (exit code {code}) on {cleaned!r}: {' | '.join(detail)}{hint}")
        phones, ends, words, word_ids = _parse_segments(self._segs)
        wav_path = Path(wav_path)
        wav_path.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(self._wav, wav_path)
        self.close()
        if not phones:
            raise FestivalError(f"Festival returned no segments for {cleaned!r}")
        duration = wav_duration(wav_path)
        starts = np.concatenate([[0.0], ends[:-1]])
        ends_a = np.asarray(ends, dtype=float)
        keep = ends_a > starts
        return FestivalUtterance(
            text=cleaned,
            phones=tuple(p for p, k in zip(phones, keep) if k),
            starts=np.ascontiguousarray(starts[keep]),
            ends=np.ascontiguousarray(ends_a[keep]),
            wav=wav_path,
            duration=duration,
            dropped=tuple(p for p, k in zip(phones, keep) if not k),
            words=tuple(w for w, k in zip(words, keep) if k),
            word_ids=tuple(w for w, k in zip(word_ids, keep) if k),
        )


# Festival 2.5 ignores a Duration_Stretch below 0.1 (the /casa/ of pc_diphone lasts 1.04 s at 1,
# 0.099 and 0.05, 0.114 s at 0.1: `(Parameter.set 'Duration_Stretch S)` then `utt.synth`).
MIN_STRETCH = 0.1


def start_synthesis(
    text: str,
    *,
    stretch: float = 1.0,
    voice: str | None = None,
    festival: str = "festival",
    timeout: float = 300.0,
    lang: str = "it",
) -> Synthesis:
    """Start Festival on `text` and return at once (`Synthesis.result` waits); the text, rate and
    voice are checked first, so that a bad one is an error before anything runs.

    `voice` defaults to the language's (`LANGUAGES`: pc_diphone for "it", kal_diphone for "en").
    `stretch` is Festival's Duration_Stretch: 1 the voice's own rate, 0.6 about 1.7 times faster.
    """
    default_voice, _, packages = language(lang)
    voice = default_voice if voice is None else voice
    cleaned = prepare_text(check_text(text))
    if not (math.isfinite(stretch) and stretch >= MIN_STRETCH):
        raise FestivalError(f"--stretch {stretch:g}: the speaking-rate stretch must be a finite number of at least "
                            f"{MIN_STRETCH:g} (Festival speaks at its normal rate when Duration_Stretch is below it); "
                            f"{MIN_STRETCH:g} is about {1 / MIN_STRETCH:g} times as fast as normal")
    if not _VOICE_NAME.match(voice):
        raise FestivalError(f"voice name {voice!r} is not a Festival voice name (letters, digits, _)")
    return Synthesis(cleaned, voice, packages, festival_program(festival), float(stretch), timeout)


def synthesize(
    text: str,
    wav_path: str | Path,
    *,
    stretch: float = 1.0,
    voice: str | None = None,
    festival: str = "festival",
    timeout: float = 300.0,
    lang: str = "it",
) -> FestivalUtterance:
    """Synthesise `text` with Festival into `wav_path` and return its segments (`start_synthesis`,
    then its result).

    Zero-length segments (Festival gives a few) have no time for a target and are dropped; their
    names are kept in `dropped`.
    """
    with start_synthesis(text, stretch=stretch, voice=voice, festival=festival, timeout=timeout, lang=lang) as run:
        return run.result(wav_path)
