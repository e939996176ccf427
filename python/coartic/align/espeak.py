"""espeak-ng as a TTS that reports its phone times: its C library (the Debian package espeak-ng,
libespeak-ng.so.1) called through ctypes, synthesising into memory with phoneme events in IPA.

The library's synchronous mode calls back with each block of samples and the events that fall in
it: a WORD event (its character position and length in the text) before the word's phonemes, a
PHONEME event at the sample where each phoneme starts. A phoneme lasts until the next one; pauses
and word-boundary marks come as phonemes with an empty IPA string.
"""

from __future__ import annotations

import ctypes
import threading
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from coartic.align.errors import AlignError

_LIBRARY = "libespeak-ng.so.1"
_INSTALL_HINT = "install the Debian package espeak-ng (scripts/setup.sh does)"
# espeak_AUDIO_OUTPUT, espeak_EVENT_TYPE and option flags of speak_lib.h
_AUDIO_OUTPUT_SYNCHRONOUS = 2
_INITIALIZE_PHONEME_EVENTS = 0x0001
_INITIALIZE_PHONEME_IPA = 0x0002
_EVENT_LIST_TERMINATED, _EVENT_WORD, _EVENT_PHONEME = 0, 1, 7
_CHARS_UTF8 = 1
_POS_CHARACTER = 1


class _EventId(ctypes.Union):
    _fields_ = [("number", ctypes.c_int), ("name", ctypes.c_char_p), ("string", ctypes.c_char * 8)]


class _Event(ctypes.Structure):
    _fields_ = [("type", ctypes.c_int), ("unique_identifier", ctypes.c_uint), ("text_position", ctypes.c_int),
                ("length", ctypes.c_int), ("audio_position", ctypes.c_int), ("sample", ctypes.c_int),
                ("user_data", ctypes.c_void_p), ("id", _EventId)]


_CALLBACK = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.POINTER(ctypes.c_short), ctypes.c_int, ctypes.POINTER(_Event))
_lock = threading.Lock()  # the library keeps one synthesiser per process
_state: dict[str, Any] = {}


@dataclass(frozen=True)
class EspeakSpeech:
    """What espeak-ng said: samples, and per phone its IPA (\"\" for a pause), start sample and word
    (the word's index in `words`, -1 outside words)."""

    samples: NDArray[np.float64]
    rate: int
    phones: tuple[str, ...]
    starts: NDArray[np.int64]
    ends: NDArray[np.int64]
    word_of: tuple[int, ...]
    words: tuple[str, ...]


def _library() -> tuple[Any, int]:
    if "lib" not in _state:
        try:
            lib = ctypes.CDLL(_LIBRARY)
        except OSError:
            raise AlignError(f"espeak-ng's library {_LIBRARY} is not installed ({_INSTALL_HINT})") from None
        rate = lib.espeak_Initialize(_AUDIO_OUTPUT_SYNCHRONOUS, 0, None,
                                     _INITIALIZE_PHONEME_EVENTS | _INITIALIZE_PHONEME_IPA)
        if rate <= 0:
            raise AlignError(f"espeak-ng could not start (espeak_Initialize returned {rate}; {_INSTALL_HINT})")
        _state["lib"], _state["rate"] = lib, int(rate)
    return _state["lib"], int(_state["rate"])


def speak(text: str, voice: str) -> EspeakSpeech:
    """Say `text` with espeak-ng's voice `voice` (a language code: de, it, en, fr, es, ...)."""
    with _lock:
        lib, rate = _library()
        if lib.espeak_SetVoiceByName(voice.encode("utf-8")) != 0:
            raise AlignError(f"espeak-ng has no voice {voice!r} (espeak-ng --voices lists them; {_INSTALL_HINT})")
        chunks: list[NDArray[np.int16]] = []
        events: list[tuple[int, int, int, int, str]] = []

        def collect(wav: Any, n: int, ev: Any) -> int:
            if n > 0:
                chunks.append(np.ctypeslib.as_array(wav, shape=(n,)).copy())
            i = 0
            while ev[i].type != _EVENT_LIST_TERMINATED:
                e = ev[i]
                label = bytes(e.id.string).split(b"\0")[0].decode("utf-8", "replace") if e.type == _EVENT_PHONEME else ""
                events.append((e.type, e.sample, e.text_position, e.length, label))
                i += 1
            return 0

        callback = _CALLBACK(collect)  # kept alive until espeak_Synchronize returns
        lib.espeak_SetSynthCallback(callback)
        data = text.encode("utf-8") + b"\0"
        err = lib.espeak_Synth(data, len(data), 0, _POS_CHARACTER, 0, _CHARS_UTF8, None, None)
        lib.espeak_Synchronize()
        lib.espeak_SetSynthCallback(None)
    if err != 0:
        raise AlignError(f"espeak-ng could not say the text (espeak_Synth returned {err})")
    samples = (np.concatenate(chunks).astype(np.float64) / 32768.0) if chunks else np.zeros(0)
    words: list[str] = []
    phones: list[str] = []
    starts: list[int] = []
    word_of: list[int] = []
    current = -1
    for kind, sample, pos, length, label in events:
        if kind == _EVENT_WORD:
            words.append(text[pos - 1: pos - 1 + length])
            current = len(words) - 1
        elif kind == _EVENT_PHONEME:
            phones.append(label)
            starts.append(sample)
            word_of.append(current if label else -1)
    if not phones:
        raise AlignError(f"espeak-ng said no phone for {text!r}")
    ends = [*starts[1:], len(samples)]
    keep = [e > s for s, e in zip(starts, ends)]  # word-boundary marks last no time
    return EspeakSpeech(
        samples=samples, rate=rate,
        phones=tuple(p for p, k in zip(phones, keep) if k),
        starts=np.array([s for s, k in zip(starts, keep) if k], dtype=np.int64),
        ends=np.array([e for e, k in zip(ends, keep) if k], dtype=np.int64),
        word_of=tuple(w for w, k in zip(word_of, keep) if k),
        words=tuple(words),
    )
