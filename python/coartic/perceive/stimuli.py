"""The study's videos: coartic's face saying each item with Festival's voice, one video per item x
condition x SNR, nothing written on screen. The face is the 3-D one (`render = "3d"`, the default:
the glTF that `coartic speak --gltf` writes, drawn frame by frame by `coartic view`'s renderer in one
headless Chromium per item and condition, coartic.face.viewer.render_frames) or the runtime's 2-D
preview (`render = "2d"`: lips and jaw, front and side, coartic.runtime.preview).

A condition's face is the table's coarticulated animation (`model`; with an `emotion`, the table's
emotion blended in as `coartic speak --emotion` does: the lips' emotional targets and, on the 3-D
face, the expression outside the mouth, brows, lids and cheeks, from the same FAPs as the FAP file's,
coartic.runtime.expression; the 2-D preview has no brows, lids or cheeks), the same table with each
phoneme's target held over its segment (`step`: keyframe lip-sync, the runtime's analogue of the
fit's step baseline, coartic.evaluation.baselines), or the face at rest (`still`: the audio-alone baseline
of audiovisual intelligibility). Festival speaks each item once per table; every condition of an
item shares that table's timing, and every stimulus of an item the first table's sound.

Noise is mixed at the stated SNR: 10 log10(P_speech / P_noise), both powers over the samples of
the speech segments (not the pauses around them). `speech-shaped` noise has the long-term spectrum
of all the study's speech (Welch), `white` a flat one; each stimulus draws its own noise from the
study's seed. The speech is set to SPEECH_DBFS (RMS over its segments) in every stimulus, then the
mixture scaled down as a whole if a peak would clip (the SNR is unchanged).
"""

from __future__ import annotations

import json
import secrets
import shutil
import wave
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from coartic.perceive.spec import Condition, StudySpec
from coartic.runtime.animate import Animation
from coartic.runtime.errors import AnimationError
from coartic.table import PAUSE, ParameterTable

FORMAT = "coartic-perceive-study 1"
SPEECH_DBFS = -26.0
PEAK_LIMIT = 0.98  # of full scale
F64 = NDArray[np.float64]


@dataclass
class Speech:
    """One item as one table says it: the animation and Festival's sound."""

    animation: Animation
    table: ParameterTable
    samples: F64  # in [-1, 1]
    rate: int


def read_wav(path: Path) -> tuple[F64, int]:
    """A mono 16-bit PCM WAV (Festival's) as floats in [-1, 1], and its rate."""
    with wave.open(str(path), "rb") as w:
        if w.getsampwidth() != 2 or w.getnchannels() != 1:
            raise AnimationError(f"{path}: expected mono 16-bit PCM, got {w.getnchannels()} channels of "
                             f"{8 * w.getsampwidth()} bits")
        data = np.frombuffer(w.readframes(w.getnframes()), dtype="<i2")
        return data.astype(np.float64) / 32768.0, w.getframerate()


def write_wav(path: Path, samples: F64, rate: int) -> None:
    from coartic.outputs import atomic_path

    pcm = np.clip(np.rint(samples * 32767.0), -32768, 32767).astype("<i2")
    with atomic_path(path) as tmp:
        with wave.open(str(tmp), "wb") as w:
            w.setnchannels(1)
            w.setsampwidth(2)
            w.setframerate(rate)
            w.writeframes(pcm.tobytes())


def step_animation(animation: Animation, table: ParameterTable) -> Animation:
    """No coarticulation: every frame shows the target of the phoneme whose segment it falls in
    (keyframe lip-sync; frames past the last segment keep its target)."""
    seg = animation.segments
    at = np.minimum(np.searchsorted(seg.ends, animation.times, side="right"), len(seg) - 1)
    channels = dict(animation.channels)
    for c in animation.modelled:
        targets = np.array([table.values[label][c]["target"] for label in seg.labels])
        channels[c] = targets[at]
    return replace(animation, channels=channels, sample_times={})


def still_animation(animation: Animation) -> Animation:
    """The face at rest for the whole utterance (the sound alone carries the speech)."""
    channels = {c: np.full(animation.n_frames, animation.neutral[c]) for c in animation.channels}
    return replace(animation, channels=channels, sample_times={})


def speech_mask(animation: Animation, n: int, rate: int) -> NDArray[np.bool_]:
    """The audio samples inside a non-pause segment."""
    t = np.arange(n) / rate
    seg = animation.segments
    mask = np.zeros(n, dtype=bool)
    for label, s, e in zip(seg.labels, seg.starts, seg.ends):
        if label != PAUSE:
            mask |= (t >= s) & (t < e)
    if not mask.any():
        raise AnimationError("the utterance has only pauses: no speech to set an SNR against")
    return mask


def speech_spectrum(speech: list[Speech]) -> tuple[F64, F64]:
    """The long-term average spectrum (frequencies, power density) of the speech segments of all items."""
    from scipy.signal import welch

    rate = speech[0].rate
    parts = [s.samples[speech_mask(s.animation, s.samples.size, s.rate)] for s in speech]
    f, p = welch(np.concatenate(parts), fs=rate, nperseg=min(512, sum(x.size for x in parts)))
    return np.asarray(f, dtype=np.float64), np.asarray(p, dtype=np.float64)


def make_noise(n: int, rate: int, kind: str, spectrum: tuple[F64, F64] | None, rng: np.random.Generator) -> F64:
    """Gaussian noise of n samples, white or shaped to `spectrum` (unit-free: the caller sets its level)."""
    white = rng.standard_normal(n)
    if kind == "white":
        return white
    assert spectrum is not None
    freqs = np.fft.rfftfreq(n, 1.0 / rate)
    gain = np.sqrt(np.interp(freqs, spectrum[0], spectrum[1]))
    return np.asarray(np.fft.irfft(np.fft.rfft(white) * gain, n), dtype=np.float64)


def mix_at_snr(samples: F64, mask: NDArray[np.bool_], noise: F64 | None, snr_db: float | None) -> tuple[F64, float | None]:
    """Speech set to SPEECH_DBFS over `mask`, plus `noise` at `snr_db` (None: none); the mixture
    scaled down as a whole if it would clip. Returns it and the SNR measured on what was written."""
    speech = samples * (10 ** (SPEECH_DBFS / 20) / np.sqrt(np.mean(samples[mask] ** 2)))
    if snr_db is None or noise is None:
        mixed, scaled_noise = speech, None
    else:
        p_speech = np.mean(speech[mask] ** 2)
        scaled_noise = noise * np.sqrt(p_speech / 10 ** (snr_db / 10) / np.mean(noise[mask] ** 2))
        mixed = speech + scaled_noise
    peak = float(np.max(np.abs(mixed)))
    k = min(1.0, PEAK_LIMIT / peak) if peak > 0 else 1.0
    measured = None
    if scaled_noise is not None:
        s, nz = np.rint(k * speech * 32767.0), np.rint(k * scaled_noise * 32767.0)  # what the PCM holds
        measured = float(10 * np.log10(np.mean(s[mask] ** 2) / np.mean(nz[mask] ** 2)))
    return k * mixed, measured


def _table_key(c: Condition) -> tuple[str, str | None, float | None]:
    return (str(c.table) if c.table is not None else "", c.emotion, c.intensity)


def condition_table(c: Condition) -> ParameterTable:
    """The table a condition speaks with: its file (default: the shipped table), with its emotion
    blended in at its intensity (coartic.emotions.emotion_table, as `coartic speak --emotion`)."""
    if c.table is not None:
        table = ParameterTable.load(c.table)
    else:
        from coartic.runtime.shipped import load_shipped_table

        table = load_shipped_table()
    if c.emotion is None:
        return table
    from coartic.emotions import emotion_table

    return emotion_table(table, c.emotion, 1.0 if c.intensity is None else c.intensity)


def speak_item(text: str, table: ParameterTable, spec: StudySpec, work: Path, name: str) -> Speech:
    """Festival says `text`; the runtime animates it with `table` (coartic.runtime.pipeline.speak_text)."""
    from coartic.runtime.pipeline import speak_text

    out = speak_text(text, table, work / name, fps=spec.fps, preview="none", name=name, lang=spec.lang)
    samples, rate = read_wav(out.files["wav"])
    return Speech(out.animation, table, samples, rate)


def face_of(c: Condition, speech: Speech) -> Animation:
    if c.face == "step":
        return step_animation(speech.animation, speech.table)
    if c.face == "still":
        return still_animation(speech.animation)
    return speech.animation


# The 3-D face's zoom in the videos: the whole face, raised brows to chin (the camera aims at the lip
# line; closer, surprise's brows leave the frame).
STIMULUS_ZOOM = 1.1


def face_frames_3d(animation: Animation, table: ParameterTable, work: Path, size_px: int) -> list[Any]:
    """The 3-D face playing `animation` (`size_px` square RGB frames): its glTF written by the runtime's
    exporters (the one FaceAnimation the FAP file and the glTF are made from, coartic.runtime.exporters)
    into `work`, drawn frame by frame in headless Chromium by `coartic view`'s renderer."""
    from coartic.face.viewer import render_frames, write_page
    from coartic.runtime.exporters import ExportSettings, run_exports
    from coartic.runtime.pipeline import speaker_face

    settings = ExportSettings(out=work, name="face", face=speaker_face(table), table=table)
    run_exports(animation, settings, ("channels", "fap", "segments", "gltf"))
    return render_frames(write_page(work), size_px, zoom=STIMULUS_ZOOM)


def prepare_stimuli(spec: StudySpec, out: Path, progress: Any = None) -> dict[str, Any]:
    """Render every stimulus into out/stimuli and write out/study.json (the manifest the server and
    the analysis read) and out/secret.key (the key that pseudonymises panel identifiers)."""
    from coartic.outputs import atomic_write_text
    from coartic.runtime.preview import render_face_video, write_video

    if spec.render == "3d":  # before Festival says anything: without Chromium no 3-D face
        from coartic.face.viewer import chromium_program

        try:
            chromium_program()
        except AnimationError as err:
            raise AnimationError(f"{spec.path}: [stimuli] render = \"3d\" draws the face in Chromium: {err}; "
                                 "or set render = \"2d\" (the runtime's preview face)") from None
    work = out / "work"
    stim_dir = out / "stimuli"
    stim_dir.mkdir(parents=True, exist_ok=True)
    tables: dict[tuple[str, str | None, float | None], ParameterTable] = {}
    for c in spec.conditions:
        if _table_key(c) not in tables:
            tables[_table_key(c)] = condition_table(c)
    task = progress.add_task("stimuli", total=spec.n_stimuli()) if progress is not None else None
    # Festival once per item and table
    spoken: dict[tuple[int, tuple[str, str | None, float | None]], Speech] = {}
    for i, text in enumerate(spec.items):
        for c in spec.conditions:
            key = (i, _table_key(c))
            if key not in spoken:
                spoken[key] = speak_item(text, tables[key[1]], spec, work, f"item{i + 1}_{len(spoken)}")
    first = {i: spoken[(i, _table_key(spec.conditions[0]))] for i in range(len(spec.items))}
    spectrum = speech_spectrum(list(first.values())) if spec.noise == "speech-shaped" else None
    stimuli: list[dict[str, Any]] = []
    for i, text in enumerate(spec.items):
        sound = first[i]
        mask = speech_mask(sound.animation, sound.samples.size, sound.rate)
        for k, c in enumerate(spec.conditions):
            speech = spoken[(i, _table_key(c))]
            animation = face_of(c, speech)
            # the 3-D face drawn once per item and condition: its SNRs differ in their sound only
            frames = (face_frames_3d(animation, speech.table, work / f"face{i + 1}_{k + 1}", spec.size_px)
                      if spec.render == "3d" else None)
            for snr in spec.snr_db:
                sid = f"s{len(stimuli) + 1:04d}"
                rng = np.random.default_rng([spec.seed, len(stimuli)])
                noise = None if snr is None else make_noise(sound.samples.size, sound.rate, spec.noise, spectrum, rng)
                mixed, measured = mix_at_snr(sound.samples, mask, noise, snr)
                wav = work / f"{sid}.wav"
                write_wav(wav, mixed, sound.rate)
                if frames is not None:
                    video = write_video(stim_dir / f"{sid}.mp4", frames, animation.fps, wav)
                else:
                    video = render_face_video(animation, animation.neutral, stim_dir / f"{sid}.mp4", wav, spec.size_px)
                stimuli.append({"id": sid, "item": i, "text": text, "condition": c.name, "snr_db": snr,
                                "measured_snr_db": measured, "file": f"stimuli/{video.name}",
                                "duration_s": round(sound.samples.size / sound.rate, 4),
                                "frames": animation.n_frames})
                if task is not None:
                    progress.advance(task)
    shutil.rmtree(work)
    manifest = manifest_of(spec, stimuli)
    atomic_write_text(out / "study.json", json.dumps(manifest, indent=1, ensure_ascii=False) + "\n")
    atomic_write_text(out / "secret.key", secrets.token_hex(32) + "\n")
    return manifest


def manifest_of(spec: StudySpec, stimuli: list[dict[str, Any]]) -> dict[str, Any]:
    """The study as the server and the analysis read it (study.json)."""
    if spec.design == "intelligibility":
        choices = list(spec.choices) or list(dict.fromkeys(spec.answers))
    elif spec.design == "emotion":
        choices = list(dict.fromkeys([*[c.answer or c.emotion or "" for c in spec.conditions], *spec.choices]))
    else:
        choices = list(spec.choices)
    return {
        "format": FORMAT,
        "name": spec.name, "design": spec.design, "seed": spec.seed, "title": spec.title, "consent": spec.consent,
        "instructions": spec.instructions, "question": spec.question, "response": spec.response,
        "attention_every": spec.attention_every, "counterbalance": spec.counterbalance, "replay": spec.replay,
        "completion_code": spec.completion_code, "noise": spec.noise, "lang": spec.lang, "fps": spec.fps,
        "render": spec.render,
        "items": [{"index": i, "text": t, "answer": spec.answers[i] if spec.answers else None}
                  for i, t in enumerate(spec.items)],
        "conditions": [{"name": c.name, "face": c.face, "table": None if c.table is None else str(c.table),
                        "emotion": c.emotion, "intensity": c.intensity, "answer": c.answer or c.emotion,
                        "reference": c.reference, "anchor": c.anchor} for c in spec.conditions],
        "snr_db": list(spec.snr_db),
        "choices": choices,
        "stimuli": stimuli,
    }
