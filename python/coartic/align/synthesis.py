"""The transcript said by a TTS that reports its phone times: Festival (Italian, English) or
espeak-ng (German and the other languages it has a voice for), as one `Spoken` at the aligner's
rate, its phones mapped to the model's phonemes."""

from __future__ import annotations

import math
import re
import tempfile
import unicodedata
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from coartic.align.audio import RATE
from coartic.align.errors import AlignError
from coartic.io.labelmap import IPA_TABLE
from coartic.runtime.festival import LANGUAGES, PhoneMap
from coartic.table import PAUSE

ENGINES = ("festival", "espeak")
# Silence added before and after the synthetic speech (s): the recording's own leading and trailing
# silence is warped onto it instead of onto the first and last phones.
PAD = 0.2
# Marks that espeak-ng's IPA phone names carry beside the phone itself: length, stress, syllabicity,
# palatalisation, aspiration and its own "-" (a reduced variant); combining marks (nasal ~) too.
_MARKS = re.compile("[ːˑˈˌ\\-ʲʰ̩]")


@dataclass(frozen=True)
class Spoken:
    """A transcript as a TTS said it: samples at RATE, and per phone its label in the TTS's phone
    set ("" for a pause), model phoneme, start and end (s), and word (index into `words`, -1 for
    a pause)."""

    samples: NDArray[np.float64]
    phones: tuple[str, ...]
    phonemes: tuple[str, ...]
    starts: NDArray[np.float64]
    ends: NDArray[np.float64]
    word_of: tuple[int, ...]
    words: tuple[str, ...]
    engine: str
    phone_map: PhoneMap

    @property
    def duration(self) -> float:
        return len(self.samples) / RATE


def default_engine(lang: str) -> str:
    """Festival for the languages it has a voice for here (Italian, English), espeak-ng for the rest."""
    return "festival" if lang in LANGUAGES else "espeak"


@lru_cache(maxsize=1)
def ipa_map() -> PhoneMap:
    """phones_ipa.tsv (coartic.io's labelmaps, also the label map 'ipa'): espeak-ng's IPA phones → model phonemes."""
    return PhoneMap.load(Path(str(resources.files("coartic.io").joinpath("labelmaps", IPA_TABLE))))


def ipa_phone(phone: str) -> str:
    """The phones_ipa.tsv entry of one of espeak-ng's IPA phones: its length, stress and other
    marks dropped, a diphthong by its first vowel (where the lips start), an affricate whole;
    an AlignError for a phone with no entry."""
    known = ipa_map().phonemes
    base = unicodedata.normalize("NFC", "".join(ch for ch in unicodedata.normalize("NFD", _MARKS.sub("", phone))
                                                if not unicodedata.combining(ch)))
    for key in (base, base[:2], base[:1]):
        if key and key in known:
            return key
    raise AlignError(f"espeak-ng phone {phone!r} has no entry in phones_ipa.tsv; add a line "
                     f"'{base}<TAB>phoneme<TAB>fallbacks<TAB>why'")


def split_text(text: str, max_words: int = 60) -> list[str]:
    """The transcript in parts of at most `max_words` words, cut after a sentence (or, in a long
    sentence, a clause) so that each is said as a whole: long recordings are aligned part by part."""
    words = text.split()
    if len(words) <= max_words:
        return [" ".join(words)] if words else []
    parts: list[str] = []
    current: list[str] = []
    for w in words:
        current.append(w)
        strong = w[-1:] in ".!?;:"
        weak = w[-1:] in ",)\u2014-"
        if (strong and len(current) >= max_words // 3) or (weak and len(current) >= max_words // 2) \
                or len(current) >= max_words:
            parts.append(" ".join(current))
            current = []
    if current:
        parts.append(" ".join(current))
    return parts


def _resample(x: NDArray[np.float64], rate: int) -> NDArray[np.float64]:
    from scipy.signal import resample_poly

    if rate == RATE:
        return x
    g = math.gcd(rate, RATE)
    return np.asarray(resample_poly(x, RATE // g, rate // g), dtype=np.float64)


def _padded(samples: NDArray[np.float64], phones: list[str], phonemes: list[str], starts: list[float],
            ends: list[float], word_of: list[int], words: tuple[str, ...], engine: str, pmap: PhoneMap) -> Spoken:
    """PAD of silence at each end, as (or merged into) a pause."""
    pad = np.zeros(int(PAD * RATE))
    s = np.asarray(starts) + PAD
    e = np.asarray(ends) + PAD
    if phonemes[0] == PAUSE:
        s[0] = 0.0
    else:
        phones, phonemes, word_of = ["", *phones], [PAUSE, *phonemes], [-1, *word_of]
        s, e = np.concatenate([[0.0], s]), np.concatenate([[PAD], e])
    total = len(samples) / RATE + 2 * PAD
    if phonemes[-1] == PAUSE:
        e[-1] = total
    else:
        phones, phonemes, word_of = [*phones, ""], [*phonemes, PAUSE], [*word_of, -1]
        s, e = np.concatenate([s, [e[-1]]]), np.concatenate([e, [total]])
    return Spoken(np.concatenate([pad, samples, pad]), tuple(phones), tuple(phonemes), s, e, tuple(word_of), words,
                  engine, pmap)


def speak_festival(text: str, lang: str) -> Spoken:
    from coartic.align.audio import read_recording
    from coartic.runtime.festival import synthesize

    pmap = PhoneMap.load(lang=lang)
    with tempfile.TemporaryDirectory(prefix="coartic-align-") as tmp:
        utt = synthesize(text, Path(tmp) / "said.wav", lang=lang)
        samples = read_recording(utt.wav).samples
    phonemes = pmap.to_phonemes(utt.phones)
    # Festival's word numbers run over the whole utterance; the words tier counts from 0
    ids = sorted({w for w in utt.word_ids if w >= 0})
    index = {w: k for k, w in enumerate(ids)}
    words = tuple(next(utt.words[i] for i in range(len(utt.phones)) if utt.word_ids[i] == w) for w in ids)
    word_of = [index.get(w, -1) for w in utt.word_ids]
    phones = ["" if p == PAUSE else ph for ph, p in zip(utt.phones, phonemes)]
    return _padded(samples, phones, phonemes, list(utt.starts), list(utt.ends), word_of, words, "festival", pmap)


def speak_espeak(text: str, lang: str) -> Spoken:
    from coartic.align.espeak import speak

    said = speak(text, lang)
    pmap = ipa_map()
    keys = [ipa_phone(p) if p else "" for p in said.phones]
    phonemes = [pmap.phonemes[k] if k else PAUSE for k in keys]
    return _padded(_resample(said.samples, said.rate), list(said.phones), phonemes,
                   list(said.starts / said.rate), list(said.ends / said.rate), list(said.word_of), said.words,
                   "espeak", pmap)


def speak_transcript(text: str, lang: str, engine: str | None = None) -> Spoken:
    """`text` said in `lang` by `engine` (default: `default_engine(lang)`)."""
    engine = engine or default_engine(lang)
    if engine == "festival":
        if lang not in LANGUAGES:
            raise AlignError(f"Festival has no voice for language {lang!r} here (it speaks "
                             f"{', '.join(LANGUAGES)}); use --engine espeak")
        return speak_festival(text, lang)
    if engine == "espeak":
        return speak_espeak(text, lang)
    raise AlignError(f"--engine {engine!r} is not an aligner that speaks (known: {', '.join(ENGINES)}, or sphinx)")
