"""The recording: read and checked (a WAV, not silent, not longer than asked), resampled to the
aligner's rate, and its MFCC frames.

MFCCs come from python_speech_features (the plain Davis-Mermelstein recipe, NumPy only); the WAV
is read by SciPy, memory-mapped, so that a file too long to align is refused from its header
without reading it.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from coartic.align.errors import AlignError

RATE = 16000  # Hz: the aligner's rate (PocketSphinx's en-us model is trained at 16 kHz)
HOP = 0.010  # s between MFCC frames
WINDOW = 0.025  # s of an MFCC frame
N_CEPSTRA = 13
# The longest recording aligned unless asked otherwise (--max-duration): alignment by synthesis
# synthesises the whole transcript, and a file this long is more often the wrong file.
MAX_DURATION = 3600.0
# Level (dBFS) under which a 25 ms frame is silence, and the least a recording must have of
# frames above it to hold speech at all. A quiet room is -60 dBFS or less; speech is -30 to -10.
SILENCE_DBFS = -45.0
MIN_SPEECH = 0.1  # s
_FLOOR = 1e-10


@dataclass(frozen=True)
class Recording:
    """A mono recording at RATE, samples in [-1, 1]."""

    path: Path
    samples: NDArray[np.float64]
    source_rate: int
    duration: float


def _to_float(data: NDArray[np.generic], path: Path) -> NDArray[np.float64]:
    if data.dtype == np.uint8:  # 8-bit WAV is unsigned
        return (data.astype(np.float64) - 128.0) / 128.0
    if np.issubdtype(data.dtype, np.integer):
        return np.asarray(data, dtype=np.float64) / float(-np.iinfo(str(data.dtype)).min)
    if np.issubdtype(data.dtype, np.floating):
        out = data.astype(np.float64)
        if not np.all(np.isfinite(out)):
            raise AlignError(f"{path}: the WAV holds samples that are not finite numbers (NaN or infinity)")
        return out
    raise AlignError(f"{path}: WAV samples of type {data.dtype} are not audio")


def read_recording(path: str | PathLike[str], max_duration: float = MAX_DURATION) -> Recording:
    """The recording at `path` as mono 16 kHz, or an AlignError naming the file and the fix:
    not a WAV, empty, longer than `max_duration` seconds, or silent."""
    import warnings

    from scipy.io import wavfile
    from scipy.signal import resample_poly

    p = Path(path)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", wavfile.WavFileWarning)  # unknown chunks (LIST, cue) are fine
            rate, data = wavfile.read(p, mmap=True)
    except FileNotFoundError:
        raise AlignError(f"{p}: no such file") from None
    except (ValueError, EOFError, OSError, MemoryError, struct.error) as err:
        raise AlignError(f"{p}: not a readable WAV file ({err}); convert it to PCM WAV, e.g. "
                         f"ffmpeg -i IN -ac 1 -ar 16000 -c:a pcm_s16le OUT.wav") from None
    n = data.shape[0]
    if n == 0 or rate <= 0:
        raise AlignError(f"{p}: the WAV has no samples")
    duration = n / float(rate)
    if duration > max_duration:
        raise AlignError(f"{p}: the recording lasts {_hms(duration)}, more than the {_hms(max_duration)} "
                         "aligned at once (--max-duration); cut it into parts at pauses (e.g. sox IN OUT "
                         "trim START LENGTH) and align each with its own transcript, or raise --max-duration")
    if rate < 8000:
        raise AlignError(f"{p}: sampled at {rate} Hz; speech needs at least 8000 Hz")
    mono = _to_float(np.asarray(data), p)
    if mono.ndim == 2:
        mono = mono.mean(axis=1)
    g = math.gcd(RATE, int(rate))
    samples = mono if rate == RATE else resample_poly(mono, RATE // g, int(rate) // g)
    rec = Recording(p, np.ascontiguousarray(samples, dtype=np.float64), int(rate), duration)
    speech = speech_frames(rec.samples)
    if speech.sum() * HOP < MIN_SPEECH:
        loudest = float(frame_levels(rec.samples).max()) if len(rec.samples) else -math.inf
        raise AlignError(f"{p}: no speech: the recording is silent (its loudest 25 ms is at {loudest:.0f} dBFS, "
                         f"speech is above {SILENCE_DBFS:g}); is it the right file, or recorded with the "
                         "microphone muted?")
    return rec


def is_pcm_wav(path: str | PathLike[str]) -> bool:
    """Whether Python's wave module (what the runtime copies and plays) reads the file: integer PCM."""
    import wave

    try:
        with wave.open(str(path), "rb"):
            return True
    except (wave.Error, EOFError, OSError):
        return False


def write_pcm16(src: str | PathLike[str], dest: Path) -> Path:
    """`src` (any WAV SciPy reads: float, 24-bit, WAVE_FORMAT_EXTENSIBLE) as 16-bit PCM at its own rate
    and channels, so that players and the runtime's copy take it."""
    from scipy.io import wavfile

    from coartic.outputs import atomic_path

    rate, data = wavfile.read(src, mmap=True)
    pcm = np.clip(_to_float(np.asarray(data), Path(src)), -1.0, 1.0)
    dest.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(dest) as tmp:
        wavfile.write(tmp, rate, np.round(pcm * 32767).astype(np.int16))
    return dest


def _hms(seconds: float) -> str:
    s = int(round(seconds))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


def frame_levels(samples: NDArray[np.float64]) -> NDArray[np.float64]:
    """Level (dBFS) of each 25 ms frame, every HOP s."""
    win, hop = int(WINDOW * RATE), int(HOP * RATE)
    if len(samples) < win:
        samples = np.pad(samples, (0, win - len(samples)))
    n = 1 + (len(samples) - win) // hop
    idx = np.arange(win)[None, :] + hop * np.arange(n)[:, None]
    power = np.mean(samples[idx] ** 2, axis=1)
    return np.asarray(10.0 * np.log10(power + _FLOOR), dtype=np.float64)


def speech_frames(samples: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Frames louder than SILENCE_DBFS."""
    return np.asarray(frame_levels(samples) > SILENCE_DBFS)


def mfcc(samples: NDArray[np.float64], rate: int = RATE) -> NDArray[np.float64]:
    """Frames x 24: MFCC 1-12 and their deltas, each normalised to zero mean and unit variance
    over the sequence (c0, the level, is left out: two speakers, two microphones)."""
    from python_speech_features import delta
    from python_speech_features import mfcc as psf_mfcc

    if len(samples) < int(WINDOW * rate):
        samples = np.pad(samples, (0, int(WINDOW * rate) - len(samples)))
    # a whisper of noise: digital silence (a TTS's) has no spectrum, and log(0) would rule the distances
    rng = np.random.default_rng(0)
    x = samples + 1e-4 * rng.standard_normal(len(samples))
    c = np.asarray(psf_mfcc(x, samplerate=rate, winlen=WINDOW, winstep=HOP, numcep=N_CEPSTRA, nfilt=26,
                            nfft=512 if rate <= 16000 else 1024, appendEnergy=False), dtype=np.float64)[:, 1:]
    feats = np.hstack([c, np.asarray(delta(c, 2), dtype=np.float64)])
    sd = feats.std(axis=0)
    return np.asarray((feats - feats.mean(axis=0)) / np.where(sd > 0, sd, 1.0), dtype=np.float64)
