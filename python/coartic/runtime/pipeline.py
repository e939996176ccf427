"""The two things the runtime does end to end: animate a label file, and speak an Italian (or English) text.

Each writes into one output directory: the channels (CSV), the FAP file, the segments animated,
and (optionally) the preview; `speak` adds Festival's WAV. The cheap, exact outputs are written
first and every file atomically, so an interrupted preview loses nothing else.
"""

from __future__ import annotations

import os
import re
import shutil
import unicodedata
import wave
from dataclasses import dataclass, field, replace
from os import PathLike
from pathlib import Path

import numpy as np
from rich.progress import Progress

from coartic.io.labelmap import LabelMap, resolve_label_map
from coartic.io.labels import Segments, read_labels
from coartic.runtime import PREVIEW_FORMATS
from coartic.runtime.animate import (
    Animation,
    animate,
    neutral_posture,
    split_final_pause,
    substitute,
    table_channels,
)
from coartic.runtime.errors import AnimationError, MissingPhonemeError
from coartic.runtime.exporters import ExportSettings, RigOptions, parse_exports, run_exports
from coartic.runtime.fap import FaceUnits, FapSequence
from coartic.runtime.markup import apply_to_utterance
from coartic.runtime.festival import (FestivalUtterance, PhoneMap, Synthesis, check_text, prepare_text,
                                      start_synthesis, wav_duration)
from coartic.speakers import SpeakerMapping, speaker_mapping
from coartic.table import PAUSE, ParameterTable


@dataclass
class RuntimeOutput:
    """What was written, and the animation behind it."""

    animation: Animation
    faps: FapSequence
    files: dict[str, Path] = field(default_factory=dict)
    utterance: FestivalUtterance | None = None


def speaker_face(table: ParameterTable, mns_mm: float | None = None, mw_mm: float | None = None,
                 speaker: str | None = None) -> FaceUnits:
    """FAPU of the face the table describes: MPEG-4 values are in the encoding face's units, and a
    player rescales them to its own face. MW defaults to the rest mouth width (the pause's LR
    target, the speaker's with ``speaker``); MNS, which no channel measures, to FaceUnits' 30 mm."""
    default = FaceUnits()
    mw = speaker_neutral(table, speaker_mapping(table, speaker), ["LR"])["LR"] if mw_mm is None else mw_mm
    return FaceUnits(mns_mm=default.mns_mm if mns_mm is None else mns_mm, mw_mm=mw)


def speaker_neutral(table: ParameterTable, mapping: SpeakerMapping | None,
                    channels: tuple[str, ...] | list[str] | None = None) -> dict[str, float]:
    """The neutral posture (the pause's targets) of the table's speaker ``mapping`` (None: the table's own)."""
    chans = list(channels) if channels is not None else None
    if mapping is None:
        return neutral_posture(table) if chans is None else neutral_posture(table, chans)
    own = mapping.evaluation_table(table)
    rest = neutral_posture(own) if chans is None else neutral_posture(own, chans)
    return {c: float(mapping.apply(c, np.array([v]))[0]) if c in own.channels else v for c, v in rest.items()}


def speak_as(animation: Animation, mapping: SpeakerMapping | None, table: ParameterTable | None = None) -> Animation:
    """The animation's modelled channels as the speaker says them (a + b·F; coartic.speakers), with
    that speaker's neutral face (from `table`, the multi-speaker table)."""
    if mapping is not None:
        for c in animation.modelled:
            animation.channels[c] = mapping.apply(c, animation.channels[c])
        animation = replace(animation, speaker=mapping)
        if table is not None:
            return replace(animation, neutral=speaker_neutral(table, mapping))
    return animation


def _name_from(text: str) -> str:
    # FAP files are ASCII and their name is one word: "Perché no?" -> "Perche_no"
    ascii_text = unicodedata.normalize("NFKD", text).encode("ascii", "ignore").decode()
    word = re.sub(r"[^0-9A-Za-z_]+", "_", ascii_text).strip("_")
    return word[:40] or "coartic"


_NAME = re.compile(r"[0-9A-Za-z_][0-9A-Za-z_.-]*")


def check_name(name: str) -> str:
    """A FAP name as players read it: one ASCII word, also the stem of the WAV and glTF beside it."""
    if not _NAME.fullmatch(name) or len(name) > 80:
        raise AnimationError(f"FAP name {name!r} must be one ASCII word (letters, digits, _ . -), at most 80 "
                             "characters: it is the FAP header's name and the stem of the .fap, .wav and .glb")
    return name


def copy_audio(src: str | PathLike[str], dest: Path) -> tuple[Path, float]:
    """Copy the user's WAV to `dest` (through a .part name) after checking it reads; its duration in s."""
    src = Path(src)
    try:
        with wave.open(str(src), "rb") as w:
            if w.getnframes() == 0:
                raise AnimationError(f"{src}: the WAV has no samples")
    except (wave.Error, EOFError) as err:
        raise AnimationError(f"{src}: not a PCM WAV file ({err}); convert it, e.g. ffmpeg -i IN -c:a pcm_s16le OUT.wav") from None
    except OSError as err:
        raise AnimationError(f"{src}: cannot read the audio ({err.strerror})") from None
    dest.parent.mkdir(parents=True, exist_ok=True)
    if src.resolve() != dest.resolve():
        tmp = dest.with_name(dest.name + ".part")
        shutil.copyfile(src, tmp)
        os.replace(tmp, dest)
    return dest, wav_duration(dest)


def _check_rig(rig: RigOptions | None, exports: tuple[str, ...]) -> None:
    if rig is not None and rig.shape_scale:
        from coartic.runtime.rigs import check_shape_scale

        check_shape_scale(rig, exports)


def _check_preview(preview: str) -> None:
    if preview not in PREVIEW_FORMATS:
        raise AnimationError(f"preview must be one of {', '.join(PREVIEW_FORMATS)}, got {preview!r}")


def _write_outputs(
    animation: Animation,
    table: ParameterTable,
    out: Path,
    name: str,
    face: FaceUnits,
    preview: str,
    requested: tuple[str, ...],
    source: tuple[str, ...],
    progress: Progress | None,
    audio: Path | None = None,
    gltf: bool = False,
    vrml: bool = False,
    mapping: SpeakerMapping | None = None,
    exports: tuple[str, ...] = (),
    gltf_morphs: str = "fap",
    rig: RigOptions | None = None,
) -> RuntimeOutput:
    """Every exporter fed the one animation: the exact outputs first, the pictures last."""
    if not animation.neutral:
        neutral_posture(table)  # raises, naming the table: no pause phoneme, no neutral face
    settings = ExportSettings(out=out, name=name, face=face, table=table, requested=requested, source=source,
                              audio=audio, progress=progress, mapping=mapping, gltf_morphs=gltf_morphs,
                              preview=preview, rig=rig or RigOptions())
    if audio is not None:
        settings.files["wav"] = audio
    names = ["channels", "fap", "segments", *(["gltf"] if gltf else []), *(["vrml"] if vrml else []), *exports,
             *(["plot", "preview"] if preview != "none" else [])]
    fed = run_exports(animation, settings, names)
    return RuntimeOutput(animation=animation, faps=fed.faps, files=settings.files)


def animate_file(
    labels: str | PathLike[str],
    table: ParameterTable,
    out: str | PathLike[str],
    *,
    fps: float = 25.0,
    tier: str | None = None,
    label_map: LabelMap | str | None = None,
    face: FaceUnits | None = None,
    preview: str = "gif",
    snap_contacts: bool = True,
    strict: bool = False,
    phone_map: PhoneMap | None = None,
    progress: Progress | None = None,
    audio: str | PathLike[str] | None = None,
    name: str | None = None,
    gltf: bool = False,
    vrml: bool = False,
    speaker: str | None = None,
    exports: str | tuple[str, ...] | list[str] | None = None,
    gltf_morphs: str = "fap",
    rig: RigOptions | None = None,
) -> RuntimeOutput:
    """A label file (.lab / TextGrid / TSV) → channels, FAP file and preview in `out`.

    The labels are mapped by `label_map`, by default the map the table was fitted with
    (`LabelMap.recorded`; the model phone set for a table that records none). Phonemes the table lacks are replaced by the phone map's fallbacks
    unless `strict`. With `audio` (the recording the labels describe), the WAV is copied beside
    the FAP file under its name (Greta loads `name.fap` with `name.wav`), the animation lasts as
    long as the sound, and the MP4 preview and the glTF bundle carry it. `name` defaults to the
    label file's stem. `exports`: the rigs' curves and cues ("arkit", "visemes", "rhubarb"; a list
    or comma-separated); `gltf_morphs`: the glTF's morph set, "fap", "arkit" or "eight" (coartic.runtime.exporters). `speaker`: one of the speakers of a table fitted with `[model] speakers`
    (its offset and scale, or its own targets; coartic.speakers). `rig`: how the rigs' curves
    and cues are written (coartic.runtime.exporters.RigOptions).
    """
    _check_preview(preview)
    wanted = parse_exports(exports)
    _check_rig(rig, wanted)
    mapping = speaker_mapping(table, speaker)
    out = Path(out)
    name = check_name(name) if name is not None else _name_from(Path(labels).stem)
    raw = read_labels(labels, tier=tier)
    lmap = resolve_label_map(label_map) if label_map is not None else LabelMap.recorded(table)
    segments = (lmap or LabelMap.model()).apply(raw)
    requested = segments.labels
    used: dict[str, str] = {}
    if not strict:
        segments, used = substitute(segments, table, table_channels(table),
                                    (phone_map or PhoneMap.load()).fallbacks)
    wav: Path | None = None
    duration = None
    if audio is not None:
        wav, duration = copy_audio(audio, out / f"{name}.wav")
        # labels that run on after the sound are for another recording (or another rate)
        if segments.end_time > duration + 1.0 / fps:
            raise AnimationError(f"{labels}: the labels run to {segments.end_time:.3f} s but {audio} lasts "
                                 f"{duration:.3f} s; are they for this recording?")
        duration = max(duration, 1.0 / fps)
    segments, origin = split_final_pause(segments)
    own = table if mapping is None else mapping.evaluation_table(table)
    animation = speak_as(animate(own, segments, fps, duration=duration, snap_contacts=snap_contacts,
                                 substitutions=used), mapping, table)
    return _write_outputs(animation, table, out, name, face or speaker_face(table, speaker=speaker),
                          preview, tuple(requested[i] for i in origin), tuple(raw.labels[i] for i in origin),
                          progress, audio=wav, gltf=gltf, vrml=vrml, mapping=mapping,
                          exports=wanted, gltf_morphs=gltf_morphs, rig=rig)


def speak_text(
    text: str,
    table: ParameterTable,
    out: str | PathLike[str],
    *,
    fps: float = 25.0,
    stretch: float = 1.0,
    voice: str | None = None,
    face: FaceUnits | None = None,
    strict: bool = False,
    phone_map: PhoneMap | None = None,
    preview: str = "gif",
    festival: str = "festival",
    snap_contacts: bool = True,
    progress: Progress | None = None,
    name: str | None = None,
    gltf: bool = False,
    vrml: bool = False,
    speaker: str | None = None,
    exports: str | tuple[str, ...] | list[str] | None = None,
    gltf_morphs: str = "fap",
    lang: str = "it",
    synthesis: Synthesis | None = None,
    rig: RigOptions | None = None,
) -> RuntimeOutput:
    """Text → Festival's WAV, and channels, FAP file and preview lasting as long as the WAV.

    `lang` "it" (Festival's Italian voice, phones_italian.tsv) or "en" (its English voice,
    phones_english.tsv: ARPAbet phones onto the model's phonemes); `voice` defaults to the
    language's. The WAV is written as `name.wav` beside `name.fap` (Greta loads them by the shared
    name); `name` defaults to a word made of the text.

    Phonemes the table lacks are replaced by the phone map's fallbacks (reported in
    `animation.substitutions`) unless `strict`. `speaker`: as in `animate_file`. `synthesis`: Festival
    already started on this text (`start_synthesis`, with the same rate, voice and language), so that
    it ran while the caller imported and loaded; by default it is started here.
    """
    _check_preview(preview)
    wanted = parse_exports(exports)
    _check_rig(rig, wanted)
    mapping = speaker_mapping(table, speaker)
    check_text(text)
    out = Path(out)
    pmap = phone_map or PhoneMap.load(lang=lang)
    name = check_name(name) if name is not None else _name_from(text)
    if synthesis is not None and synthesis.text != prepare_text(text):
        raise AnimationError(f"Festival was started on {synthesis.text!r}, not on {prepare_text(text)!r}")
    run = synthesis or start_synthesis(text, stretch=stretch, voice=voice, festival=festival, lang=lang)
    with run:
        utt = run.result(out / f"{name}.wav")
    # an emotion markup's words, now timed: its spans (coartic.runtime.markup; any other table as it is)
    table = apply_to_utterance(table, utt)
    phonemes = pmap.to_phonemes(utt.phones)
    ends = utt.ends.copy()
    # Festival's WAV runs a few ms past the last segment: the final pause lasts to the end of the sound.
    if phonemes[-1] == PAUSE and utt.duration > ends[-1]:
        ends[-1] = utt.duration
    segments = Segments(tuple(phonemes), utt.starts, ends)
    requested = segments.labels
    used: dict[str, str] = {}
    if not strict:
        segments, used = substitute(segments, table, table_channels(table), pmap.fallbacks)
    segments, origin = split_final_pause(segments)
    try:
        animation = speak_as(animate(table if mapping is None else mapping.evaluation_table(table), segments, fps,
                                     duration=utt.duration, substitutions=used, snap_contacts=snap_contacts), mapping, table)
    except MissingPhonemeError as err:
        if err.segment is None:
            raise
        raise MissingPhonemeError(f"{err} (Festival phone {utt.phones[origin[err.segment]]!r} of {utt.text!r})",
                                  origin[err.segment]) from None
    result = _write_outputs(animation, table, out, name, face or speaker_face(table, speaker=speaker), preview,
                            tuple(requested[i] for i in origin), tuple(utt.phones[i] for i in origin), progress,
                            audio=utt.wav, gltf=gltf, vrml=vrml, mapping=mapping,
                            exports=wanted, gltf_morphs=gltf_morphs, rig=rig)
    result.utterance = utt
    return result
