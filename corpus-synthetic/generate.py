"""Generate the synthetic ELITE-style session of CORPUS.md: VCV trials as C3D, CSV and labels.

    coartic corpus synth OUT [--seed N] [--quick] [--flavour model|gestures|italian]
    python corpus-synthetic/generate.py OUT [...]            (the same)

Every trial is # V C V # with V in {i, a, u} and C every Italian consonant, at a normal and a fast
rate, 5 repetitions. The six channels come from the modified model (``coartic.model.trajectories``)
with the ground-truth table ``ground_truth.json`` (or, ``--flavour gestures``, from critically damped
gestures towards the same targets: gestures.py); the markers are then placed in a head frame so
that MODEL.md §6 gives those channels back, moved rigidly (slow head motion), perturbed with
Gaussian noise and occasional occlusions. All settings are in ``session.toml`` next to this file.

``--flavour italian`` covers every Italian phoneme: all seven vowels /i e E a O o u/ in VCV, CV and
VC contexts with every consonant (``session.toml [italian]``), from ``ground_truth_italian.json``.
Its truth also has the tongue channels TTH TTA TBH TBA, which a face-marker set cannot carry, so
each of its trials is written a second time as an EMA recording (``ema/<trial>.csv``: the lips,
the jaw and two tongue sensors, head-corrected as EMA systems deliver them; ``session.toml [ema]``).

Each trial draws from its own random stream, seeded by (seed, vowel, consonant, rate, repetition):
a trial is the same whether it is generated in the full session or in a ``--quick`` one.
"""

from __future__ import annotations

import copy
import csv
import functools
import importlib.util
import json
import math
import re
import shutil
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import ezc3d
import numpy as np
import numpy.typing as npt
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn
from scipy.spatial.transform import Rotation

from coartic.model import trajectories
from coartic.table import CHANNELS, PAUSE, TONGUE_CHANNELS, ParameterTable

HERE = Path(__file__).resolve().parent
FLAVOURS: tuple[str, ...] = ("model", "gestures", "italian", "emotive")
SETTINGS = HERE / "session.toml"
EMOTION_SETTINGS = HERE / "emotions.toml"  # the emotive flavour
ASYMMETRY: tuple[str, ...] = ("ASYMX", "ASYMY")  # the corner asymmetries of the emotive flavour
EMOTION_DYNAMICS: tuple[str, ...] = ("alpha", "theta_bw", "theta_fw")  # the rates [dynamics] may move
GROUND_TRUTH = HERE / "ground_truth.json"
GROUND_TRUTH_ITALIAN = HERE / "ground_truth_italian.json"
CONTEXTS: tuple[str, ...] = ("VCV", "CV", "VC")

F64 = npt.NDArray[np.float64]
MARKERS: tuple[str, ...] = ("NOSE", "EAR_L", "EAR_R", "UL", "LL", "LC_L", "LC_R", "CHIN")
# The EMA recording of the Italian flavour: sensors named as EMA labs name them (docs/DATA.md).
EMA_SENSORS: tuple[str, ...] = ("UL", "LL", "JAW", "TT", "TB")
RATES: tuple[str, ...] = ("normal", "fast")
MANIFEST_COLUMNS: tuple[str, ...] = (
    "file", "labels", "stimulus", "vowel", "consonant", "repetition", "rate",
    "csv", "lab", "truth", "n_frames", "duration_s", "dropout_frames", "y0_offset_mm",
)
# File names must stay distinct on case-insensitive file systems (S/s, L/l, E/e, O/o), so phonemes
# are spelled in plain lower-case ASCII there; the labels and the manifest keep the model phonemes.
FILE_SPELLING = {"tS": "tsh", "dZ": "dzh", "S": "sh", "J": "gn", "L": "gli", "E": "eh", "O": "oh"}


class SessionError(ValueError):
    """A bad setting or output directory; the message names the file and the setting at fault."""


@dataclass(frozen=True)
class TrialPlan:
    """One trial of the session, before anything is drawn."""

    vowel: str
    consonant: str
    rate: str
    repetition: int  # 1-based
    # (vowel, consonant, rate, repetition) indices, and the context's for the Italian flavour: the RNG stream
    key: tuple[int, ...]
    context: str = "VCV"  # VCV, or (Italian flavour) CV or VC between pauses
    emotion: str = ""  # the emotive flavour's emotion ("neutral", "joy", ...); "" in the other flavours
    intensity: float = 1.0  # the emotive flavour's intensity: the emotion's deviations scaled by it

    @property
    def phonemes(self) -> tuple[str, ...]:
        """The stimulus between its pauses."""
        v, c = self.vowel, self.consonant
        return {"VCV": (v, c, v), "CV": (c, v), "VC": (v, c)}[self.context]

    @property
    def name(self) -> str:
        spelt = "".join(FILE_SPELLING.get(p, p) for p in self.phonemes)
        if self.emotion:
            at = "" if self.intensity == 1.0 else f"-{self.intensity:g}"
            return f"{spelt}_{self.emotion}{at}_{self.rate}_{self.repetition:02d}"
        return f"{spelt}_{self.rate}_{self.repetition:02d}"

    @property
    def stimulus(self) -> str:
        return " ".join(self.phonemes)


@dataclass
class Trial:
    """A generated trial: segments, the noise-free truth and the recorded markers."""

    plan: TrialPlan
    labels: list[str]
    starts: F64
    ends: F64
    times: F64
    channels: dict[str, F64]  # the generated channel trajectories (the truth), mm
    head_markers: F64  # [F, 8, 3] noise-free, head frame
    markers: F64  # [F, 8, 3] lab frame, noise and NaN dropouts
    dropouts: list[tuple[str, int, int]]  # (marker, first frame, n frames)
    y0_offset: float  # how far §6's y_0 (mean over the first pause) lies from the rest line, mm
    ema: F64 | None = None  # [F, 5, 3] EMA sensors (EMA_SENSORS; x lateral, y backwards, z up), noisy


# ----------------------------------------------------------------------------- settings


def load_settings(path: Path = SETTINGS) -> dict[str, Any]:
    """Read ``session.toml`` and check what the generator relies on."""
    try:
        with open(path, "rb") as fh:
            s = tomllib.load(fh)
    except OSError as exc:
        raise SessionError(f"{path}: cannot read the session settings: {exc.strerror}") from None
    except tomllib.TOMLDecodeError as exc:
        raise SessionError(f"{path}: invalid TOML: {exc}") from None
    for key in ("seed", "rate_hz", "repetitions", "quick_repetitions", "vowels", "consonants",
                "pause_label", "time_resolution", "durations", "geometry", "head_motion", "noise", "gestures",
                "italian"):
        if key not in s:
            raise SessionError(f"{path}: missing setting {key!r}")
    it = s["italian"]
    for key in ("vowels", "consonants", "contexts", "repetitions", "quick_repetitions"):
        if key not in it:
            raise SessionError(f"{path}: missing setting 'italian.{key}'")
    bad = [c for c in it["contexts"] if c not in CONTEXTS]
    if bad or not it["contexts"]:
        raise SessionError(f"{path}: italian.contexts must be some of {list(CONTEXTS)}, got {it['contexts']!r}")
    if not 0 < it["quick_repetitions"] <= it["repetitions"]:
        raise SessionError(f"{path}: italian.quick_repetitions must be in 1..italian.repetitions")
    d = s["durations"]
    for v in dict.fromkeys([*s["vowels"], *it["vowels"]]):
        for part in ("first_vowel", "second_vowel"):
            if v not in d.get(part, {}):
                raise SessionError(f"{path}: [durations.{part}] has no duration for vowel {v!r}")
    for c in dict.fromkeys([*s["consonants"], *it["consonants"]]):
        if c not in d.get("consonant", {}):
            raise SessionError(f"{path}: [durations.consonant] has no duration for consonant {c!r}")
    if not 0 < s["quick_repetitions"] <= s["repetitions"]:
        raise SessionError(f"{path}: quick_repetitions must be in 1..repetitions")
    return s


def load_emotions(path: Path = EMOTION_SETTINGS) -> dict[str, Any]:
    """Read ``emotions.toml`` (the emotive flavour) and check it: every emotion's deviations name
    known channels and classes, every phoneme is in one class, the bilabials never move ULO/LLO and
    the labiodentals never LLO (their contacts are phonological), every emotion has its asymmetry."""
    try:
        with open(path, "rb") as fh:
            e = tomllib.load(fh)
    except OSError as exc:
        raise SessionError(f"{path}: cannot read the emotion settings: {exc.strerror}") from None
    except tomllib.TOMLDecodeError as exc:
        raise SessionError(f"{path}: invalid TOML: {exc}") from None
    for key in ("emotions", "vowels", "consonants", "repetitions", "quick_repetitions", "intensity", "classes",
                "deviation", "asymmetry"):
        if key not in e:
            raise SessionError(f"{path}: missing setting {key!r}")
    if not e["emotions"] or e["emotions"][0] != "neutral":
        raise SessionError(f"{path}: emotions must start with \"neutral\" (the reference), got {e['emotions']!r}")
    if not 0 < e["quick_repetitions"] <= e["repetitions"]:
        raise SessionError(f"{path}: quick_repetitions must be in 1..repetitions")
    e["intensities"] = check_intensities(e["intensity"], f"{path}: intensity")
    e.setdefault("dynamics", {})
    e["planted_dynamics"] = False  # generate(emotion_dynamics=True) plants [dynamics]
    for emotion, devs in e["dynamics"].items():
        if emotion not in e["emotions"] or emotion == "neutral":
            raise SessionError(f"{path}: [dynamics.{emotion}]: not one of the emotions {e['emotions'][1:]}")
        for q, v in devs.items():
            per = v if isinstance(v, dict) else {"*": v}
            if q not in EMOTION_DYNAMICS or any(isinstance(f, bool) or not isinstance(f, (int, float)) or f <= 0
                                               for f in per.values()):
                raise SessionError(f"{path}: [dynamics.{emotion}] {q}: expected one of {list(EMOTION_DYNAMICS)} = a "
                                   "positive factor or {class = factor, ...}")
            bad = [c for c in per if c != "*" and c not in e["classes"]]
            if bad:
                raise SessionError(f"{path}: [dynamics.{emotion}] {q}: unknown class(es) {bad}")
    owner: dict[str, str] = {}
    for cls, members in e["classes"].items():
        for ph in members:
            if ph in owner:
                raise SessionError(f"{path}: phoneme {ph!r} is in [classes] {owner[ph]} and {cls}")
            owner[ph] = cls
    missing = [ph for ph in [PAUSE, *e["vowels"], *e["consonants"]] if ph not in owner]
    if missing:
        raise SessionError(f"{path}: phoneme(s) {missing} in no [classes] entry")
    for emotion, devs in e["deviation"].items():
        if emotion not in e["emotions"] or emotion == "neutral":
            raise SessionError(f"{path}: [deviation.{emotion}]: not one of the emotions {e['emotions'][1:]}")
        for ch, v in devs.items():
            if ch not in CHANNELS:
                raise SessionError(f"{path}: [deviation.{emotion}] {ch}: not a channel ({', '.join(CHANNELS)})")
            per = v if isinstance(v, dict) else {cls: v for cls in e["classes"]}
            bad = [c for c in per if c not in e["classes"]]
            if bad:
                raise SessionError(f"{path}: [deviation.{emotion}] {ch}: unknown class(es) {bad}")
            if ((ch in ("ULO", "LLO") and per.get("bilabial", 0.0) != 0.0 and isinstance(v, dict))
                    or (ch == "LLO" and per.get("labiodental", 0.0) != 0.0 and isinstance(v, dict))
                    or (ch in ("ULO", "LLO") and not isinstance(v, dict))):
                raise SessionError(f"{path}: [deviation.{emotion}] {ch}: the lips' closure on /p b m/ and the lower "
                                   "lip's contact on /f v/ must not move (give the classes it applies to)")
    for emotion in e["emotions"]:
        if emotion not in e["asymmetry"]:
            raise SessionError(f"{path}: [asymmetry] has no entry for {emotion!r}")
        if set(e["asymmetry"][emotion]) - set(ASYMMETRY):
            raise SessionError(f"{path}: [asymmetry] {emotion}: keys must be {list(ASYMMETRY)}")
    return e


def check_intensities(value: Any, where: str) -> list[float]:
    """The intensities every emotion is said at (a number or a list of distinct numbers in (0, 1.5];
    the neutral trials once): the emotion's deviations scaled by each."""
    values = value if isinstance(value, list) else [value]
    if (not values or any(isinstance(v, bool) or not isinstance(v, (int, float)) or not 0.0 < v <= 1.5 for v in values)
            or len(set(values)) != len(values)):
        raise SessionError(f"{where}: expected a number in (0, 1.5] or a list of distinct ones, got {value!r}")
    return [float(v) for v in values]


def emotion_deviations(emo: dict[str, Any]) -> dict[str, dict[str, dict[str, float]]]:
    """emotion -> channel -> phoneme -> deviation (mm) of every non-neutral emotion (0 where none given)."""
    owner = {ph: cls for cls, members in emo["classes"].items() for ph in members}
    out: dict[str, dict[str, dict[str, float]]] = {}
    for emotion in emo["emotions"][1:]:
        devs = emo["deviation"].get(emotion, {})
        out[emotion] = {}
        for ch in CHANNELS:
            v = devs.get(ch, 0.0)
            out[emotion][ch] = {ph: float(v.get(cls, 0.0) if isinstance(v, dict) else v) for ph, cls in owner.items()}
    return out


def emotion_dynamics(emo: dict[str, Any]) -> dict[str, dict[str, dict[str, float]]]:
    """emotion -> parameter -> phoneme -> log factor on the neutral value (every channel) of every
    non-neutral emotion and EMOTION_DYNAMICS parameter; all 0 unless the dynamics are planted."""
    owner = {ph: cls for cls, members in emo["classes"].items() for ph in members}
    out: dict[str, dict[str, dict[str, float]]] = {}
    for emotion in emo["emotions"][1:]:
        devs = emo["dynamics"].get(emotion, {}) if emo.get("planted_dynamics") else {}
        out[emotion] = {}
        for q in EMOTION_DYNAMICS:
            v = devs.get(q, 1.0)
            per = v if isinstance(v, dict) else {c: v for c in emo["classes"] if c != "pause"}
            out[emotion][q] = {ph: math.log(float(per.get(cls, 1.0))) for ph, cls in owner.items()}
    return out


def emotion_tables(table: ParameterTable, emo: dict[str, Any]) -> dict[tuple[str, float], ParameterTable]:
    """The table each emotion's trials at each intensity s are generated from: the neutral truth with
    its targets moved by s times the emotion's deviations (and, planted dynamics, its rates by factor^s)."""
    out = {("neutral", 1.0): table}
    dyn = emotion_dynamics(emo)
    for emotion, per_ch in emotion_deviations(emo).items():
        for s in emo["intensities"]:
            t = copy.deepcopy(table)
            for ch, per in per_ch.items():
                for ph, d in per.items():
                    t.values[ph][ch]["target"] += s * d
                    for q, logs in dyn[emotion].items():
                        if logs[ph]:
                            t.values[ph][ch][q] *= math.exp(s * logs[ph])
            out[emotion, s] = t
    return out


def emotive_truth(table: ParameterTable, emo: dict[str, Any]) -> ParameterTable:
    """The emotive flavour's ground truth: the neutral table (the phonemes of the flavour) with
    ``metadata.emotions`` in the shape a fit with ``[model] emotions = "targets"`` writes (each
    emotion's targets and deviations per channel) plus the corner asymmetries."""
    keep = [PAUSE, *emo["vowels"], *emo["consonants"]]
    t = copy.deepcopy(table)
    t.values = {ph: t.values[ph] for ph in keep}
    devs = emotion_deviations(emo)
    channels: dict[str, Any] = {}
    for ch in CHANNELS:
        targets = {e: {ph: t.values[ph][ch]["target"] + (devs[e][ch][ph] if e in devs else 0.0) for ph in keep}
                   for e in emo["emotions"]}
        channels[ch] = {"targets": targets, "deviations": {e: {ph: devs[e][ch][ph] for ph in keep} for e in devs}}
        if emo.get("planted_dynamics"):  # the log deviations a targets+dynamics fit estimates
            dyn = emotion_dynamics(emo)
            channels[ch]["dynamics"] = {q: {"deviations": {e: {ph: dyn[e][q][ph] for ph in keep} for e in dyn}}
                                        for q in EMOTION_DYNAMICS}
    t.metadata = {**(t.metadata or {}), "emotions": {
        "mode": "targets", "column": "emotion", "neutral": "neutral", "channels": channels,
        "asymmetry": {e: {k: float(emo["asymmetry"][e].get(k, 0.0)) for k in ASYMMETRY} for e in emo["emotions"]},
        "note": "directions from Magno Caldognetto et al. (AVSP 2003, Speech Communication 2004) as read in "
                "corpus-synthetic/emotions.toml; the millimetres are ours"}}
    t.source = "corpus-synthetic emotive flavour truth"
    return t


def plan_trials(settings: dict[str, Any], quick: bool = False, flavour: str = "model") -> list[TrialPlan]:
    """Every trial of the session (``quick``: the first ``quick_repetitions`` repetitions only).

    The Italian flavour: every vowel of ``[italian]`` in each of its contexts with every consonant.
    The emotive flavour (``settings["emotive"]``, emotions.toml): its vowels and consonants with every emotion."""
    if flavour == "emotive":
        em = settings["emotive"]
        reps = em["quick_repetitions"] if quick else em["repetitions"]
        # a trial at intensity 1 has the stream (and so the bytes) it had before intensities existed
        return [
            TrialPlan(v, c, rate, rep + 1, (vi, ci, ri, rep, ei) + (() if s == 1.0 else (si,)), "VCV", emotion, s)
            for ei, emotion in enumerate(em["emotions"])
            for si, s in enumerate(em["intensities"] if ei else [1.0])
            for vi, v in enumerate(em["vowels"])
            for ci, c in enumerate(em["consonants"])
            for ri, rate in enumerate(RATES)
            for rep in range(reps)
        ]
    if flavour == "italian":
        it = settings["italian"]
        reps = it["quick_repetitions"] if quick else it["repetitions"]
        return [
            TrialPlan(v, c, rate, rep + 1, (vi, ci, ri, rep, CONTEXTS.index(ctx)), ctx)
            for ctx in it["contexts"]
            for vi, v in enumerate(it["vowels"])
            for ci, c in enumerate(it["consonants"])
            for ri, rate in enumerate(RATES)
            for rep in range(reps)
        ]
    reps = settings["quick_repetitions"] if quick else settings["repetitions"]
    return [
        TrialPlan(v, c, rate, rep + 1, (vi, ci, ri, rep))
        for vi, v in enumerate(settings["vowels"])
        for ci, c in enumerate(settings["consonants"])
        for ri, rate in enumerate(RATES)
        for rep in range(reps)
    ]


def trial_rng(seed: int, plan: TrialPlan, stream: tuple[int, ...] = ()) -> np.random.Generator:
    """The trial's own random stream; ``stream`` (the speaker's number in a multi-speaker corpus)
    gives every speaker other draws of the same trial. Empty for a one-speaker session."""
    return np.random.default_rng(np.random.SeedSequence([seed, *plan.key, *stream]))


# ----------------------------------------------------------------------------- segments


def draw_segments(
    settings: dict[str, Any], plan: TrialPlan, rng: np.random.Generator
) -> tuple[list[str], F64, F64, F64]:
    """Labels, starts, ends (s) and sample times of ``# V C V #`` (or ``# C V #``, ``# V C #``).

    A vowel before the consonant is the stressed first vowel of /'VCV/, after it the unstressed
    second one; the vowel of a CV or VC syllable said alone is stressed. Boundaries are rounded to ``time_resolution`` so that TextGrid and HTK .lab hold them
    exactly, and the last pause is stretched (by less than one frame) to end on a frame.
    """
    d = settings["durations"]
    scale = d["fast_factor"] if plan.rate == "fast" else 1.0
    v, c = plan.vowel, plan.consonant
    stimulus = {
        "VCV": [d["first_vowel"][v], d["consonant"][c], d["second_vowel"][v]],
        "CV": [d["consonant"][c], d["first_vowel"][v]],
        "VC": [d["first_vowel"][v], d["consonant"][c]],
    }[plan.context]
    nominal = [d["lead_pause"], *(x * scale for x in stimulus), d["final_pause"]]
    jitter = rng.uniform(1.0 - d["jitter"], 1.0 + d["jitter"], size=len(nominal))
    # Dividing by an integer gives the float nearest to the decimal k / scale, which is what a
    # TextGrid (decimal text) and an HTK .lab (integer 100 ns units) read back to.
    scale = round(1.0 / settings["time_resolution"])
    bounds = np.round(np.concatenate([[0.0], np.cumsum(np.asarray(nominal) * jitter)]) * scale) / scale
    rate = float(settings["rate_hz"])
    n_frames = int(math.ceil(bounds[-1] * rate - 1e-9)) + 1
    bounds[-1] = (n_frames - 1) / rate
    bounds = np.round(bounds * scale) / scale
    times = np.arange(n_frames, dtype=np.float64) / rate
    return [PAUSE, *plan.phonemes, PAUSE], bounds[:-1].copy(), bounds[1:].copy(), times


# ----------------------------------------------------------------------------- markers


def place_markers(settings: dict[str, Any], channels: dict[str, F64], jaw_rest: float,
                  asymmetry: tuple[float, float] = (0.0, 0.0)) -> F64:
    """Markers [F, 8, 3] in the head frame whose MODEL.md §6 channels are ``channels``.

    The head frame is fixed by NOSE and the ears (origin at the ear midpoint, x towards EAR_L,
    z towards NOSE), so NOSE and the ears sit on its axes. UL and LL share the rest line y_0 at
    rest, so ULO = UL_y - y_0 and LLO = y_0 - LL_y hold exactly; the lip corners are mirror
    images (their distance is LR); CHIN lies on a ray from NOSE at distance JO, turning back as
    the jaw opens.

    ``asymmetry`` (ASYMX, ASYMY mm, the emotive flavour): the right corner's outward displacement
    minus the left's, and its height minus the left's; both corners move by the same amount in
    opposite senses, their distance staying LR.
    """
    g = settings["geometry"]
    n = len(channels["ULO"])
    m = np.zeros((n, len(MARKERS), 3))
    idx = {name: i for i, name in enumerate(MARKERS)}
    m[:, idx["NOSE"]] = (0.0, 0.0, g["nose_z"])
    m[:, idx["EAR_L"]] = (g["ear_half_width"], 0.0, 0.0)
    m[:, idx["EAR_R"]] = (-g["ear_half_width"], 0.0, 0.0)
    y0 = g["lip_line_y"]
    m[:, idx["UL"]] = np.stack([np.zeros(n), y0 + channels["ULO"], channels["ULP"]], axis=1)
    m[:, idx["LL"]] = np.stack([np.zeros(n), y0 - channels["LLO"], channels["LLP"]], axis=1)
    corner_z = channels["ULP"] + g["corner_z_offset"]
    ax, ay = asymmetry
    # x_L = half − ax/2, x_R = −half − ax/2: right outward minus left outward = ax, the distance kept
    # LR by narrowing the lateral half-width for the height difference ay
    half = np.sqrt(np.maximum(channels["LR"] ** 2 - ay**2, 0.0)) / 2.0
    m[:, idx["LC_L"]] = np.stack([half - ax / 2.0, np.full(n, g["corner_y"] - ay / 2.0), corner_z], axis=1)
    m[:, idx["LC_R"]] = np.stack([-half - ax / 2.0, np.full(n, g["corner_y"] + ay / 2.0), corner_z], axis=1)
    phi = np.radians(g["chin_angle"] + g["chin_angle_per_mm"] * (channels["JO"] - jaw_rest))
    jo = channels["JO"]
    m[:, idx["CHIN"]] = np.stack([np.zeros(n), -jo * np.cos(phi), g["nose_z"] - jo * np.sin(phi)], axis=1)
    return m


def place_ema_sensors(settings: dict[str, Any], channels: dict[str, F64], jaw_rest: float) -> F64:
    """EMA sensors [F, 5, 3] (EMA_SENSORS) whose docs/DATA.md channels are ``channels``.

    Head-corrected, as EMA systems deliver them, in the axes of an EMA CSV: x lateral, y backwards,
    z up (forwards = -y). The lip sensors sit on the vermilion, ``lip_sensor_offset`` above and below
    the face markers (y_0 is their mean, so ULO and LLO come back);
    the jaw sensor on the lower incisors drops as JO grows; the tongue sensors sit at their rest
    positions (``[ema]``) moved by the tongue channels, up and forwards.
    """
    g, e = settings["geometry"], settings["ema"]
    n = len(channels["ULO"])
    zero = np.zeros(n)

    def at(up: F64, forwards: F64) -> F64:
        return np.stack([zero, -forwards, up], axis=1)

    y0 = g["lip_line_y"]
    tt, tb, jaw = e["tongue_tip_rest"], e["tongue_body_rest"], e["jaw_rest"]  # [up, forwards] head frame
    lip = e["lip_sensor_offset"]  # on the vermilion, above and below the rest line (ULO, LLO keep y_0)
    return np.stack([
        at(y0 + lip + channels["ULO"], channels["ULP"]),
        at(y0 - lip - channels["LLO"], channels["LLP"]),
        at(jaw[0] - (channels["JO"] - jaw_rest), np.full(n, jaw[1])),
        at(tt[0] + channels["TTH"], tt[1] + channels["TTA"]),
        at(tb[0] + channels["TBH"], tb[1] + channels["TBA"]),
    ], axis=1)


def head_pose(settings: dict[str, Any], times: F64, rng: np.random.Generator) -> tuple[F64, F64]:
    """Rotation matrices [F, 3, 3] and translations [F, 3] taking the head frame to the lab.

    A per-trial constant pose change plus a slow sway (a sinusoid of random phase and frequency
    per axis) for each of the three rotation and three translation axes, on top of the head's
    place in the lab.
    """
    h, g = settings["head_motion"], settings["geometry"]
    lo, hi = h["sway_hz"]

    def sway(amplitude: float, pose: float) -> F64:
        offset = rng.uniform(-pose, pose, size=3)
        freq = rng.uniform(lo, hi, size=3)
        phase = rng.uniform(0.0, 2.0 * np.pi, size=3)
        return offset + amplitude * np.sin(2.0 * np.pi * freq * times[:, None] + phase)  # [F, 3]

    angles = sway(h["sway_deg"], h["pose_jitter_deg"])
    shifts = sway(h["sway_mm"], h["pose_jitter_mm"])
    base = Rotation.from_euler("xyz", g["lab_rotation"], degrees=True)
    rot = base * Rotation.from_euler("xyz", angles, degrees=True)
    trans = np.asarray(g["lab_position"], dtype=np.float64) + base.apply(shifts)
    return rot.as_matrix(), trans


def record(
    settings: dict[str, Any], head_markers: F64, times: F64, rng: np.random.Generator, n_session: int
) -> tuple[F64, list[tuple[str, int, int]]]:
    """What the capture system writes: lab-frame markers with noise and occlusions (NaN)."""
    rot, trans = head_pose(settings, times, rng)
    lab = np.einsum("fij,fmj->fmi", rot, head_markers) + trans[:, None, :]
    noise = settings["noise"]
    lab = lab + rng.normal(0.0, noise["sigma_mm"], size=lab.shape)
    # Occlusions: a Poisson number per marker per trial whose session total is dropouts_per_marker.
    rate = noise["dropouts_per_marker"] / n_session
    shortest, longest = noise["dropout_frames"]
    dropouts: list[tuple[str, int, int]] = []
    n = len(times)
    for mi, name in enumerate(MARKERS):
        for _ in range(rng.poisson(rate)):
            length = int(rng.integers(shortest, longest + 1))
            first = int(rng.integers(0, n - length + 1))
            lab[first : first + length, mi] = np.nan
            dropouts.append((name, first, length))
    return lab, dropouts


# ----------------------------------------------------------------------------- one trial


@functools.cache
def _gestures() -> Any:
    """corpus-synthetic/gestures.py (a sibling file, not a package module)."""
    spec = importlib.util.spec_from_file_location("coartic_corpus_synthetic_gestures", HERE / "gestures.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def make_trial(
    settings: dict[str, Any],
    table: ParameterTable,
    plan: TrialPlan,
    seed: int,
    n_session: int,
    flavour: str = "model",
    stream: tuple[int, ...] = (),
) -> Trial:
    """One trial; ``flavour`` "model", "italian" or "emotive" (MODEL.md §3 with the table: for an
    emotive trial the table of its emotion, ``emotion_tables``) or "gestures" (gestures.py)."""
    rng = trial_rng(seed, plan, stream)
    labels, starts, ends, times = draw_segments(settings, plan, rng)
    if flavour in ("model", "italian", "emotive"):
        traj = trajectories(table, labels, starts, ends, times, channels=list(CHANNELS))
    elif flavour == "gestures":
        traj = _gestures().gesture_trajectories(table, labels, starts, ends, times, settings["gestures"])
    else:
        raise SessionError(f"unknown flavour {flavour!r} (known: {', '.join(FLAVOURS)})")
    channels = {ch: np.asarray(traj[ch], dtype=np.float64) for ch in CHANNELS}
    jaw_rest = table.values[PAUSE]["JO"]["target"]
    asym = settings["emotive"]["asymmetry"][plan.emotion] if plan.emotion else {}
    head = place_markers(settings, channels, jaw_rest, (asym.get("ASYMX", 0.0), asym.get("ASYMY", 0.0)))
    markers, dropouts = record(settings, head, times, rng, n_session)
    rest = (times >= starts[0]) & (times <= ends[0])
    y0_offset = float(np.mean(channels["ULO"][rest] - channels["LLO"][rest]) / 2.0)
    ema = None
    if flavour == "italian" and all(ch in table.channels for ch in TONGUE_CHANNELS):
        # After everything above, and from a stream of its own: the face markers, and so every lip
        # and jaw channel, are the same bytes with or without the tongue.
        tongue = trajectories(table, labels, starts, ends, times, channels=list(TONGUE_CHANNELS))
        channels |= {ch: np.asarray(tongue[ch], dtype=np.float64) for ch in TONGUE_CHANNELS}
        ema_rng = np.random.default_rng(np.random.SeedSequence([seed, *plan.key, *stream], spawn_key=(1,)))
        ema = place_ema_sensors(settings, channels, jaw_rest)
        ema = ema + ema_rng.normal(0.0, settings["ema"]["sigma_mm"], size=ema.shape)
    return Trial(plan, labels, starts, ends, times, channels, head, markers, dropouts, y0_offset, ema)


# ----------------------------------------------------------------------------- writers


def write_c3d(path: Path, markers: F64, rate: float) -> None:
    """C3D through ezc3d; an occluded sample is written as C3D flags it: zeros, residual -1."""
    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [rate]
    c["parameters"]["POINT"]["LABELS"]["value"] = list(MARKERS)
    c["parameters"]["POINT"]["UNITS"]["value"] = ["mm"]
    missing = np.asarray(np.isnan(markers).any(axis=2), dtype=bool)  # [F, M]
    pts = np.ones((4, len(MARKERS), len(markers)))
    pts[:3] = np.where(missing[:, :, None], 0.0, markers).transpose(2, 1, 0)
    residuals = np.where(missing.T, -1.0, 0.0)[None, :, :]
    c["data"]["points"] = pts
    c["data"]["meta_points"] = {
        "residuals": residuals,
        "camera_masks": np.zeros((7, len(MARKERS), len(markers)), dtype=bool),
    }
    c.write(str(path))


def write_csv(path: Path, times: F64, markers: F64) -> None:
    """``time_s,<MARKER>_x,_y,_z,...`` in mm, 4 decimals (0.1 um); an occluded sample is ``nan``."""
    header = ",".join(["time_s"] + [f"{m}_{a}" for m in MARKERS for a in "xyz"])
    table = np.column_stack([times, markers.reshape(len(times), -1)])
    np.savetxt(path, table, fmt="%.4f", delimiter=",", header=header, comments="", encoding="utf-8")


def _spell(label: str, pause_label: str) -> str:
    return pause_label if label == PAUSE else label


def write_ema_csv(path: Path, times: F64, sensors: F64) -> None:
    """An EMA CSV (docs/DATA.md): ``time_s,<SENSOR>_posx,_posy,_posz,...`` in mm, 4 decimals."""
    header = ",".join(["time_s"] + [f"{s}_pos{a}" for s in EMA_SENSORS for a in "xyz"])
    table = np.column_stack([times, sensors.reshape(len(times), -1)])
    np.savetxt(path, table, fmt="%.4f", delimiter=",", header=header, comments="", encoding="utf-8")


def write_textgrid(path: Path, labels: Sequence[str], starts: F64, ends: F64, pause_label: str) -> None:
    """Praat TextGrid (long text format) with one interval tier, "phones"."""
    xmax = float(ends[-1])
    lines = [
        'File type = "ooTextFile"',
        'Object class = "TextGrid"',
        "",
        "xmin = 0 ",
        f"xmax = {xmax!r} ",
        "tiers? <exists> ",
        "size = 1 ",
        "item []: ",
        "    item [1]:",
        '        class = "IntervalTier" ',
        '        name = "phones" ',
        "        xmin = 0 ",
        f"        xmax = {xmax!r} ",
        f"        intervals: size = {len(labels)} ",
    ]
    for i, (lab, s, e) in enumerate(zip(labels, starts, ends), start=1):
        lines += [
            f"        intervals [{i}]:",
            f"            xmin = {float(s)!r} ",
            f"            xmax = {float(e)!r} ",
            f'            text = "{_spell(lab, pause_label)}" ',
        ]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def write_lab(path: Path, labels: Sequence[str], starts: F64, ends: F64, pause_label: str) -> None:
    """HTK label file: start end label, times in 100 ns units."""
    rows = [
        f"{round(float(s) * 1e7)} {round(float(e) * 1e7)} {_spell(lab, pause_label)}"
        for lab, s, e in zip(labels, starts, ends)
    ]
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")


def write_truth(path: Path, trial: Trial) -> None:
    arrays: dict[str, npt.NDArray[Any]] = {
        "times": trial.times,
        "labels": np.asarray(trial.labels),
        "starts": trial.starts,
        "ends": trial.ends,
        "head_markers": trial.head_markers,
        "marker_names": np.asarray(MARKERS),
        "dropout_mask": np.asarray(np.isnan(trial.markers).any(axis=2), dtype=bool),
    }
    arrays.update(trial.channels)
    np.savez_compressed(path, **arrays)  # type: ignore[arg-type]  # numpy stubs mix **kwds with allow_pickle


# ----------------------------------------------------------------------------- the session

SUBDIRS = ("c3d", "csv", "labels", "truth")
# The trials of the overview figure: a bilabial, a labiodental and a rounded postalveolar, and the
# bilabial again at the fast rate (its closure must still be reached).
OVERVIEW = ("apa_normal_01", "apa_fast_01", "ifi_normal_01", "ushu_normal_01")
# the emotive flavour's: one bilabial said neutrally, with joy and with surprise, and a labiodental with disgust
OVERVIEW_EMOTIVE = ("aba_neutral_normal_01", "aba_joy_normal_01", "aba_surprise_normal_01", "ava_disgust_normal_01")


def plot_overview(out: Path, gap: float, flavour: str) -> Path:
    """PNG of the overview trials: channels read back from the C3D files over the model truth."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from coartic.io import load_trial

    names = [n for n in (OVERVIEW_EMOTIVE if flavour == "emotive" else OVERVIEW) if (out / "c3d" / f"{n}.c3d").is_file()]
    if not names:  # a session of other consonants: its first trial
        names = sorted(f.stem for f in (out / "c3d").glob("*.c3d"))[:1]
    fig, axes = plt.subplots(len(CHANNELS) + 1, len(names), figsize=(4.2 * len(names), 13), sharex="col",
                             squeeze=False)
    for j, name in enumerate(names):
        with np.load(out / "truth" / f"{name}.npz") as z:
            t = {k: z[k] for k in z.files}
        got = load_trial(out / "c3d" / f"{name}.c3d", labels=out / "labels" / f"{name}.TextGrid").channels()
        rows: list[tuple[str, F64, F64]] = [(ch, t[ch], got[ch]) for ch in CHANNELS]
        rows.append(("aperture", t["ULO"] + t["LLO"] + gap, got["ULO"] + got["LLO"] + gap))
        for i, (label, model, measured) in enumerate(rows):
            ax = axes[i, j]
            ax.plot(t["times"], measured, ".", ms=2.5, color="0.45", label="read back from the C3D")
            ax.plot(t["times"], model, color="C3", lw=1.2, label="generated (truth)")
            for b in t["starts"][1:]:
                ax.axvline(b, color="0.8", lw=0.7, zorder=0)
            if label == "aperture":
                ax.axhline(0.0, color="k", lw=0.6, ls=":")
            if j == 0:
                ax.set_ylabel(f"{label} (mm)")
        top = axes[0, j]
        top.set_title(name, pad=14)
        for lab, s, e in zip(t["labels"], t["starts"], t["ends"]):
            top.annotate(str(lab), ((s + e) / 2.0, 1.0), xycoords=("data", "axes fraction"),
                         ha="center", va="bottom", fontsize=8)
        axes[-1, j].set_xlabel("time (s)")
    axes[0, 0].legend(loc="lower left", fontsize=7)
    fig.suptitle(f"Synthetic session ({flavour}): channels of MODEL.md §6 from the written markers, over the truth",
                 y=0.995)
    fig.tight_layout()
    path = out / "overview.png"
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


STAMP = ".coartic-synthetic-session"  # written first: marks a directory as ours, even half-written


def _prepare(out: Path) -> None:
    """Create ``out``; clear an earlier (or interrupted) session there, refuse anything else."""
    if out.exists() and not out.is_dir():
        raise SessionError(f"{out}: exists and is not a directory")
    # coartic_run.json: the mark of the staging directory `coartic corpus synth` writes into
    if out.is_dir() and any(p.name != "coartic_run.json" for p in out.iterdir()):
        if not (out / STAMP).is_file():
            raise SessionError(
                f"{out}: the directory is not empty and is not a synthetic session written by coartic; "
                f"choose a new or empty directory"
            )
        if (out / "manifest.csv").is_file():
            (out / "manifest.csv").unlink()  # first: an interrupted rewrite leaves no stale manifest
        for sub in (*SUBDIRS, "ema"):  # ema/: the Italian flavour's EMA recordings
            if (out / sub).is_dir():
                shutil.rmtree(out / sub)
    out.mkdir(parents=True, exist_ok=True)
    (out / STAMP).write_text("written by `coartic corpus synth`; the next run may replace this directory\n")
    for sub in SUBDIRS:
        (out / sub).mkdir(exist_ok=True)


def generate(
    out: str | Path,
    seed: int | None = None,
    quick: bool = False,
    progress: bool = True,
    flavour: str = "model",
    consonants: Sequence[str] | None = None,
    speakers: int = 1,
    intensities: Sequence[float] | None = None,
    emotion_dynamics: bool = False,
) -> Path:
    """Write the session into ``out``; return the path of its manifest.

    ``flavour``: "model" (the channels are the model's, with the ground truth), "gestures"
    (critically damped gestures towards the same targets: data the model did not make) or
    "italian" (the model with ``ground_truth_italian.json``, every Italian vowel in VCV, CV and VC
    contexts: ``session.toml [italian]``).
    ``consonants``: only the trials of these consonants (default: all of session.toml).
    ``intensities`` (emotive flavour): every emotion said at each of these intensities (default
    emotions.toml's ``intensity``), its deviations scaled by it; the manifest's intensity column says which.
    ``emotion_dynamics`` (emotive flavour): also plant emotions.toml's ``[dynamics]`` (each emotion's
    rates), recorded in the truth's ``metadata.emotions.channels.<ch>.dynamics``.
    ``speakers``: more than 1 writes one session per speaker into ``out/s01``, ``out/s02``...
    (speakers differ in target scale and speaking rate, ``speakers.toml``; each folder holds its
    speaker's ``ground_truth.json``) and a corpus manifest ``out/manifest.csv`` with a ``speaker``
    column over all of them; ``out/speakers.json`` records every speaker's scale, rate and truth.
    One speaker is the default session, the same bytes as before speakers existed.

    The manifest is written last, so a directory without one is an interrupted run (run again:
    generation is deterministic and takes seconds).
    """
    out = Path(out)
    settings = load_settings()
    seed = int(settings["seed"] if seed is None else seed)
    if seed < 0:
        raise SessionError(f"seed must be a non-negative integer, got {seed}")
    if isinstance(speakers, bool) or not isinstance(speakers, int) or speakers < 1:
        raise SessionError(f"--speakers must be a positive integer, got {speakers!r}")
    if flavour not in FLAVOURS:
        raise SessionError(f"unknown flavour {flavour!r} (known: {', '.join(FLAVOURS)})")
    if flavour == "emotive":
        if speakers != 1:
            raise SessionError("--flavour emotive is one speaker's session: leave out --speakers")
        settings = {**settings, "emotive": load_emotions()}
        if intensities is not None:
            settings["emotive"]["intensities"] = check_intensities(list(intensities), "intensities")
        settings["emotive"]["planted_dynamics"] = bool(emotion_dynamics)
    table = ParameterTable.load(truth_path(flavour))
    plans = plan_trials(settings, quick, flavour)
    if consonants is not None:
        known = {"italian": settings["italian"]["consonants"],
                 "emotive": settings.get("emotive", {}).get("consonants")}.get(flavour) or settings["consonants"]
        unknown = sorted(set(consonants) - set(known))
        if unknown:
            raise SessionError(f"{SETTINGS}: consonant(s) {unknown} are not in the session")
        plans = [p for p in plans if p.consonant in set(consonants)]
    n_session = len(plan_trials(settings, quick=False, flavour=flavour))
    if speakers == 1:
        return _write_session(out, settings, table, plans, seed, quick, progress, flavour, n_session)
    return _write_speakers(out, settings, table, plans, seed, quick, progress, flavour, n_session, speakers)


def truth_path(flavour: str) -> Path:
    """The ground-truth table a flavour is generated from."""
    return GROUND_TRUTH_ITALIAN if flavour == "italian" else GROUND_TRUTH


def manifest_columns(flavour: str) -> tuple[str, ...]:
    """The manifest's columns; the Italian flavour adds the stimulus's ``context`` (VCV, CV, VC) and
    its EMA recording (``ema``: the file column of fit/italian_tongue.toml), the emotive flavour the
    trial's ``emotion`` and ``intensity``."""
    if flavour == "emotive":
        return (*MANIFEST_COLUMNS, "emotion", "intensity")
    return (*MANIFEST_COLUMNS, "context", "ema") if flavour == "italian" else MANIFEST_COLUMNS


def _write_session(
    out: Path,
    settings: dict[str, Any],
    table: ParameterTable,
    plans: list[TrialPlan],
    seed: int,
    quick: bool,
    progress: bool,
    flavour: str,
    n_session: int,
    stream: tuple[int, ...] = (),
    title: str = "synthetic session",
) -> Path:
    """One speaker's session (the whole of a default run): trials, truth, overview, manifest last."""
    _prepare(out)
    pause_label = settings["pause_label"]
    rate = float(settings["rate_hz"])
    rows: list[dict[str, Any]] = []
    columns = (
        TextColumn(f"[bold]{title}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeRemainingColumn(),
        TextColumn("{task.description}"),
    )
    with Progress(*columns, disable=not progress, transient=False) as bar:
        task = bar.add_task("", total=len(plans))
        tables = emotion_tables(table, settings["emotive"]) if flavour == "emotive" else {}
        for plan in plans:
            trial = make_trial(settings, tables.get((plan.emotion, plan.intensity), table), plan, seed, n_session,
                               flavour, stream)
            name = plan.name
            write_c3d(out / "c3d" / f"{name}.c3d", trial.markers, rate)
            write_csv(out / "csv" / f"{name}.csv", trial.times, trial.markers)
            write_textgrid(out / "labels" / f"{name}.TextGrid", trial.labels, trial.starts, trial.ends, pause_label)
            write_lab(out / "labels" / f"{name}.lab", trial.labels, trial.starts, trial.ends, pause_label)
            write_truth(out / "truth" / f"{name}.npz", trial)
            if trial.ema is not None:
                (out / "ema").mkdir(exist_ok=True)
                write_ema_csv(out / "ema" / f"{name}.csv", trial.times, trial.ema)
            rows.append(
                {
                    "file": f"c3d/{name}.c3d",
                    "labels": f"labels/{name}.TextGrid",
                    "stimulus": plan.stimulus,
                    "vowel": plan.vowel,
                    "consonant": plan.consonant,
                    "repetition": plan.repetition,
                    "rate": plan.rate,
                    "csv": f"csv/{name}.csv",
                    "lab": f"labels/{name}.lab",
                    "truth": f"truth/{name}.npz",
                    "n_frames": len(trial.times),
                    "duration_s": f"{trial.ends[-1]:.2f}",
                    "dropout_frames": sum(n for _, _, n in trial.dropouts),
                    "y0_offset_mm": f"{trial.y0_offset:.4f}",
                } | ({"context": plan.context, "ema": f"ema/{name}.csv" if trial.ema is not None else ""}
                     if flavour == "italian" else {})
                  | ({"emotion": plan.emotion, "intensity": plan.intensity}
                     if flavour == "emotive" else {})
            )
            bar.update(task, advance=1, description=name)
    if stream:  # a speaker of a multi-speaker corpus: its own (scaled) truth
        table.save(out / "ground_truth.json")
    elif flavour == "emotive":  # the neutral truth with every emotion's (metadata.emotions)
        emotive_truth(table, settings["emotive"]).save(out / "ground_truth.json")
        shutil.copyfile(EMOTION_SETTINGS, out / "emotions.toml")
    else:
        shutil.copyfile(truth_path(flavour), out / "ground_truth.json")
    shutil.copyfile(SETTINGS, out / "session.toml")
    (out / "session.json").write_text(
        json.dumps(
            {"seed": seed, "quick": quick, "flavour": flavour, "n_trials": len(plans), "markers": list(MARKERS)},
            indent=2,
        )
        + "\n",
        encoding="utf-8",
    )
    plot_overview(out, settings["geometry"]["rest_gap"], flavour)
    manifest = out / "manifest.csv"
    with open(manifest, "w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=manifest_columns(flavour))
        w.writeheader()
        w.writerows(rows)
    return manifest


# ----------------------------------------------------------------------------- many speakers

SPEAKER_SETTINGS = HERE / "speakers.toml"
SPEAKER_DIR = re.compile(r"s\d{2,}")


@dataclass(frozen=True)
class Speaker:
    """How one synthetic speaker differs from the ground truth of ``ground_truth.json``."""

    name: str  # s01, s02, ... (the folder and the manifest's speaker column)
    number: int  # 1-based: the extra random stream of its trials
    target_scale: float  # every target's distance from the rest (pause) target is multiplied by it
    duration_scale: float  # V, C, V durations multiplied by it (> 1: a slower speaker); pauses kept


def load_speaker_settings(path: Path = SPEAKER_SETTINGS) -> dict[str, tuple[float, float]]:
    """Read ``speakers.toml``: the ranges speakers spread over."""
    try:
        with open(path, "rb") as fh:
            s = tomllib.load(fh)
    except OSError as exc:
        raise SessionError(f"{path}: cannot read the speaker settings: {exc.strerror}") from None
    except tomllib.TOMLDecodeError as exc:
        raise SessionError(f"{path}: invalid TOML: {exc}") from None
    out: dict[str, tuple[float, float]] = {}
    for key in ("target_scale", "duration_scale"):
        v = s.get(key)
        if (not isinstance(v, list) or len(v) != 2
                or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)
                or not 0 < v[0] <= v[1]):
            raise SessionError(f"{path}: {key} must be [low, high] with 0 < low <= high, got {v!r}")
        out[key] = (float(v[0]), float(v[1]))
    return out


def plan_speakers(n: int, seed: int, ranges: dict[str, tuple[float, float]]) -> list[Speaker]:
    """``n`` speakers evenly spread over both ranges; the pairing of scale and rate is shuffled by
    the seed (so that scale and rate are not simply correlated across speakers)."""
    width = max(2, len(str(n)))
    scales = np.linspace(*ranges["target_scale"], n)
    durations = np.linspace(*ranges["duration_scale"], n)
    order = np.random.default_rng(np.random.SeedSequence([seed, n])).permutation(n)
    return [Speaker(f"s{k + 1:0{width}d}", k + 1, float(scales[k]), float(durations[order[k]])) for k in range(n)]


def speaker_table(table: ParameterTable, speaker: Speaker) -> ParameterTable:
    """The ground truth scaled for one speaker: targets move away from (or towards) the rest."""
    doc = copy.deepcopy(table.to_json_dict())
    for ch in table.channels:
        rest = table.values[PAUSE][ch]["target"]
        for chans in doc["phonemes"].values():
            if ch in chans:
                chans[ch]["target"] = rest + speaker.target_scale * (chans[ch]["target"] - rest)
    doc.setdefault("metadata", {})["speaker"] = {
        "name": speaker.name, "target_scale": speaker.target_scale, "duration_scale": speaker.duration_scale,
        "rule": "target = rest target + target_scale * (ground-truth target - rest target); "
                "V, C, V durations multiplied by duration_scale",
    }
    return ParameterTable.from_json_dict(doc, source=f"{GROUND_TRUTH} for speaker {speaker.name}")


def speaker_settings(settings: dict[str, Any], speaker: Speaker) -> dict[str, Any]:
    s = copy.deepcopy(settings)
    for part in ("first_vowel", "second_vowel", "consonant"):
        s["durations"][part] = {k: v * speaker.duration_scale for k, v in s["durations"][part].items()}
    return s


def _write_speakers(
    out: Path,
    settings: dict[str, Any],
    table: ParameterTable,
    plans: list[TrialPlan],
    seed: int,
    quick: bool,
    progress: bool,
    flavour: str,
    n_session: int,
    n_speakers: int,
) -> Path:
    """One session per speaker in ``out/sNN``, then the corpus manifest over all of them."""
    speakers = plan_speakers(n_speakers, seed, load_speaker_settings())
    _prepare(out)
    for old in out.iterdir():  # speakers of an earlier run (they carry our stamp); others refused above
        if old.is_dir() and SPEAKER_DIR.fullmatch(old.name) and (old / STAMP).is_file():
            shutil.rmtree(old)
    for sub in SUBDIRS:
        (out / sub).rmdir()  # the per-speaker folders hold the trials
    rows: list[dict[str, Any]] = []
    record_: dict[str, Any] = {}
    for sp in speakers:
        truth = speaker_table(table, sp)
        manifest = _write_session(out / sp.name, speaker_settings(settings, sp), truth, plans, seed, quick,
                                  progress, flavour, n_session, stream=(sp.number,),
                                  title=f"speaker {sp.name}")
        with open(manifest, newline="", encoding="utf-8") as fh:
            for r in csv.DictReader(fh):
                for col in ("file", "labels", "csv", "lab", "truth"):
                    r[col] = f"{sp.name}/{r[col]}"
                rows.append({"speaker": sp.name, **r})
        record_[sp.name] = {"target_scale": sp.target_scale, "duration_scale": sp.duration_scale,
                            "ground_truth": f"{sp.name}/ground_truth.json", "manifest": f"{sp.name}/manifest.csv",
                            "n_trials": len(plans)}
    shutil.copyfile(SPEAKER_SETTINGS, out / "speakers.toml")
    (out / "speakers.json").write_text(
        json.dumps({"seed": seed, "quick": quick, "flavour": flavour, "speakers": record_}, indent=2) + "\n",
        encoding="utf-8",
    )
    manifest = out / "manifest.csv"
    with open(manifest, "w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=("speaker", *manifest_columns(flavour)))
        w.writeheader()
        w.writerows(rows)
    return manifest


if __name__ == "__main__":
    from coartic.synthetic_cli import run

    run()
