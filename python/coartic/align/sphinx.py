"""English with PocketSphinx (the PyPI package pocketsphinx, which ships the en-us acoustic model,
the CMU dictionary and a phone language model): forced alignment of a transcript at phone level,
and phone recognition without one, the way Rhubarb Lip Sync uses it.

Its phones are CMU ARPAbet without stress, mapped to the model's phonemes by phones_english.tsv
(the map of Festival's English voice, whose phone set is the same but lower-case).
"""

from __future__ import annotations

import re
from typing import Any

import numpy as np

from coartic.align.alignment import Alignment, Progress
from coartic.align.audio import HOP, RATE, Recording
from coartic.align.errors import AlignError
from coartic.runtime.festival import PhoneMap
from coartic.table import PAUSE

# PocketSphinx's silence and filler phones
_SILENCE = {"SIL", "+SPN+", "+NSN+", "+BREATH+", "+COUGH+", "+NOISE+", "+UM+", "+UH+", "+SMACK+"}
_WORD = re.compile(r"[a-z0-9']+")
# Share of a transcript's words missing from the English dictionary that says it is not English.
FOREIGN_SHARE = 0.3
# Beams of the alignment search, wider than PocketSphinx's recognition defaults (1e-48): an alignment
# has one path to follow, and with the defaults a voice unlike the model's (a TTS, a child) falls off it.
# bestpath off: its lattice can give a phone fewer frames than its HMM has states, and the second
# (phone) pass then fails (PocketSphinx issue 339, fixed upstream after 5.1.1).
ALIGN_BEAMS = {"beam": 1e-100, "wbeam": 1e-80, "pbeam": 1e-100, "bestpath": False}
RECOGNITION_NOTE = ("phones recognised without a transcript (PocketSphinx's phone decoder, as Rhubarb Lip Sync "
                    "does): less accurate than an alignment to the words; give --text for better lips")


def _decoder(**config: Any) -> Any:
    from pocketsphinx import Decoder

    return Decoder(samprate=RATE, loglevel="FATAL", **config)


def _pcm(recording: Recording) -> bytes:
    return np.asarray(np.clip(recording.samples, -1, 1) * 32767, dtype="<i2").tobytes()


def normalise(text: str, decoder: Any) -> list[str]:
    """The transcript as the dictionary's words (lower case, punctuation dropped); an AlignError
    naming the words the dictionary lacks."""
    words = _WORD.findall(text.lower().replace("\u2019", "'"))
    if not words:
        raise AlignError("the transcript has no English words to align")
    missing = sorted({w for w in words if decoder.lookup_word(w) is None})
    if missing:
        share = sum(w in missing for w in words) / len(words)
        hint = (f"; {100 * share:.0f} % of the words are not English words: is the transcript in English (--lang)?"
                if share >= FOREIGN_SHARE else " (spell numbers and abbreviations out)")
        raise AlignError(f"PocketSphinx's dictionary (cmudict-en-us) has no {', '.join(repr(w) for w in missing[:10])}"
                         f"{' ...' if len(missing) > 10 else ''}{hint}")
    return words


def _phone_map() -> PhoneMap:
    return PhoneMap.load(lang="en")


def _build(phones: list[tuple[str, int, int, int]], words: list[str], recording: Recording, method: str,
           note: list[str]) -> Alignment:
    """An Alignment from (phone, first frame, frames, word index) in PocketSphinx's 100 frames/s."""
    pmap = _phone_map()
    labels: list[str] = []
    phonemes: list[str] = []
    starts: list[float] = []
    word_of: list[int] = []
    for name, start, _, w in phones:
        silent = name in _SILENCE or name.startswith("+")
        label = "" if silent else name.lower()
        phoneme = PAUSE if silent else pmap.to_phonemes([label])[0]
        if phoneme == PAUSE and phonemes and phonemes[-1] == PAUSE:
            continue
        labels.append(label)
        phonemes.append(phoneme)
        starts.append(start * HOP)
        word_of.append(-1 if silent else w)
    end = recording.duration
    if not labels:
        raise AlignError(f"{recording.path}: PocketSphinx found no phone")
    s = np.array(starts)
    s[0] = 0.0
    e = np.append(s[1:], end)
    keep = e > s
    return Alignment(tuple(x for x, k in zip(labels, keep) if k), tuple(x for x, k in zip(phonemes, keep) if k),
                     s[keep], e[keep], tuple(x for x, k in zip(word_of, keep) if k), tuple(words), end, method, pmap,
                     warnings=note)


def align_sphinx(recording: Recording, text: str, progress: Progress | None = None,
                 parts: list[tuple[float, float, str]] | None = None) -> Alignment:
    """Forced alignment of `text` (English) with PocketSphinx: words, then phones within them.
    `parts`: (start, end, words) spans of the recording found by an alignment by synthesis
    (`Alignment.parts`); each is aligned alone, so that a long recording costs its length, not more,
    and progress is shown part by part."""
    if parts is not None and len(parts) > 1:
        return _align_parts(recording, parts, progress)
    decoder = _decoder(**ALIGN_BEAMS)
    words = normalise(text, decoder)
    pcm = _pcm(recording)
    try:
        decoder.set_align_text(" ".join(words))
        decoder.start_utt()
        decoder.process_raw(pcm, full_utt=True)
        decoder.end_utt()
        if decoder.hyp() is None:
            raise AlignError(f"{recording.path}: PocketSphinx could not align the transcript (the words do "
                             "not fit the sound)")
        decoder.set_alignment()
        decoder.start_utt()
        decoder.process_raw(pcm, full_utt=True)
        decoder.end_utt()
        found = decoder.get_alignment()
    except RuntimeError as err:
        raise AlignError(f"{recording.path}: PocketSphinx could not align the transcript ({err})") from None
    if found is None:
        raise AlignError(f"{recording.path}: PocketSphinx found no alignment of the transcript to the recording: "
                         "is it what the recording says, in English?")
    phones: list[tuple[str, int, int, int]] = []
    k = 0
    for word in found:
        name = word.name
        is_word = name not in ("<s>", "</s>", "<sil>") and not name.startswith("[")
        for phone in word:
            phones.append((phone.name, phone.start, phone.duration, k if is_word else -1))
        k += int(is_word)
    if progress is not None:
        progress(1, 1)
    return _build(phones, words, recording, "forced alignment by PocketSphinx (en-us model, CMU dictionary)", [])


def _align_parts(recording: Recording, parts: list[tuple[float, float, str]], progress: Progress | None) -> Alignment:
    from dataclasses import replace

    pieces: list[Alignment] = []
    for k, (start, end, words) in enumerate(parts):
        a = int(start * RATE)
        b = int(end * RATE) if k < len(parts) - 1 else len(recording.samples)
        clip = replace(recording, samples=recording.samples[a:b], duration=(b - a) / RATE)
        pieces.append(align_sphinx(clip, words))
        if progress is not None:
            progress(k + 1, len(parts))
    labels: list[str] = [""]
    phonemes: list[str] = [PAUSE]
    starts: list[float] = [0.0]
    word_of: list[int] = [-1]
    words_all: list[str] = []
    for (start, _, _), piece in zip(parts, pieces):
        offset = len(words_all)
        for lab, phm, s, w in zip(piece.phones, piece.phonemes, piece.starts, piece.word_of):
            if phm == PAUSE and phonemes[-1] == PAUSE:
                continue
            labels.append(lab)
            phonemes.append(phm)
            starts.append(start + float(s))
            word_of.append(w + offset if w >= 0 else -1)
        words_all.extend(piece.words)
    if len(starts) > 1 and starts[1] <= 0.0:
        del labels[0], phonemes[0], starts[0], word_of[0]
    s_arr = np.array(starts)
    e_arr = np.append(s_arr[1:], recording.duration)
    return Alignment(tuple(labels), tuple(phonemes), s_arr, e_arr, tuple(word_of), tuple(words_all),
                     recording.duration, pieces[0].method + f", in {len(parts)} parts", pieces[0].phone_map)


def recognise_phones(recording: Recording, progress: Progress | None = None) -> Alignment:
    """Phones recognised by PocketSphinx's phone decoder (no transcript): RECOGNITION_NOTE."""
    from pocketsphinx import get_model_path

    decoder = _decoder(allphone=get_model_path("en-us/en-us-phone.lm.bin"), lw=2.0, beam=1e-20, pbeam=1e-20)
    decoder.start_utt()
    decoder.process_raw(_pcm(recording), full_utt=True)
    decoder.end_utt()
    phones = [(seg.word, seg.start_frame, seg.end_frame - seg.start_frame + 1, -1) for seg in decoder.seg()]
    if progress is not None:
        progress(1, 1)
    return _build(phones, [], recording, "phone recognition by PocketSphinx (no transcript)", [RECOGNITION_NOTE])
