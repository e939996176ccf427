"""The study spec: one TOML file that says what is shown to whom and what they are asked.

```toml
[study]
name = "vcv-noise"              # one word: the study's name in the database and the files
design = "intelligibility"      # intelligibility | emotion | preference | mushra
seed = 20261128                 # every participant's randomisation derives from it
title = "Which consonant?"
consent = "..."                 # shown on the first page; the participant must agree
instructions = "..."            # shown above every trial
attention_every = 8             # an attention check after every 8 trials (0: none)
counterbalance = "full"         # full: every participant sees every stimulus; latin: each item once
                                # per SNR, its condition rotated over participants (Latin square)

[stimuli]
items = ["aba", "ada", "aga"]   # texts Festival speaks (lang "it" or "en")
response = "choice"             # intelligibility: choice (closed set) or text (typed, scored by words)
answers = ["b", "d", "g"]       # the right answer of each item (default for VCV items: the consonant)
snr_db = [-6.0, 0.0]            # noise mixed into the sound at these SNRs (intelligibility: required)
noise = "speech-shaped"         # or "white"
render = "3d"                   # the face in the videos: "3d" (coartic's face, coartic view's renderer in a
                                # headless Chromium: brows, lids, cheeks, teeth) or "2d" (the runtime's
                                # preview: lips, jaw, front and side, no Chromium needed)

[[condition]]
name = "coarticulation"         # the fitted table's face
table = "fitted.json"           # default: the table shipped with coartic
face = "model"                  # model | step (each phoneme's target held over its segment) | still
```
"""

from __future__ import annotations

import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from coartic.errors import SpecError
from coartic.textfile import TextDecodeError, read_text

DESIGNS = ("intelligibility", "emotion", "preference", "mushra")
FACES = ("model", "step", "still")
NOISES = ("speech-shaped", "white")
RESPONSES = ("choice", "text")
RENDERS = ("3d", "2d")
COUNTERBALANCE = ("full", "latin")
_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,63}")
_VCV = re.compile(r"([aeiouAEIOU])([^aeiouAEIOU]+)\1")
MAX_STIMULI = 5000  # renders of about a second each: past this a typo in a list is likelier than a study


@dataclass(frozen=True)
class Condition:
    """One way of animating the face: a table, a kind of face, and (with the runtime's emotions) an emotion."""

    name: str
    face: str = "model"
    table: Path | None = None  # None: the shipped table
    emotion: str | None = None
    intensity: float | None = None
    answer: str | None = None  # emotion design: the right answer (default: the emotion)
    reference: bool = False  # MUSHRA: the hidden reference
    anchor: bool = False  # MUSHRA: the anchor


@dataclass(frozen=True)
class StudySpec:
    """A study as the TOML says it, checked; `path` locates the relative table paths."""

    path: Path
    name: str
    design: str
    seed: int
    title: str
    consent: str
    instructions: str
    question: str
    items: tuple[str, ...]
    answers: tuple[str, ...]
    conditions: tuple[Condition, ...]
    response: str = "choice"
    snr_db: tuple[float | None, ...] = (None,)
    noise: str = "speech-shaped"
    lang: str = "it"
    fps: float = 25.0
    size_px: int = 240
    render: str = "3d"
    attention_every: int = 8
    counterbalance: str = "full"
    replay: bool = False
    choices: tuple[str, ...] = ()
    completion_code: str = ""
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def condition_names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.conditions)

    def n_stimuli(self) -> int:
        return len(self.items) * len(self.conditions) * len(self.snr_db)


def _fail(path: Path, key: str | None, message: str) -> SpecError:
    return SpecError.at(path, key, message)


def _take(doc: dict[str, Any], path: Path, section: str, allowed: set[str]) -> None:
    unknown = sorted(set(doc) - allowed)
    if unknown:
        raise _fail(path, f"{section}.{unknown[0]}", f"unknown key (known in [{section}]: {', '.join(sorted(allowed))})")


def _str(v: Any, path: Path, key: str, default: str | None = None) -> str:
    if v is None:
        if default is None:
            raise _fail(path, key, "is required")
        return default
    if not isinstance(v, str):
        raise _fail(path, key, f"must be a string, got {v!r}")
    return v


def _choice(v: Any, path: Path, key: str, options: tuple[str, ...], default: str | None = None) -> str:
    s = _str(v, path, key, default)
    if s not in options:
        raise _fail(path, key, f"must be one of {', '.join(options)}, got {s!r}")
    return s


def _int(v: Any, path: Path, key: str, default: int, lo: int, hi: int) -> int:
    if v is None:
        return default
    if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
        raise _fail(path, key, f"must be a whole number in [{lo}, {hi}], got {v!r}")
    return v


def _float(v: Any, path: Path, key: str, lo: float, hi: float) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not lo <= float(v) <= hi:
        raise _fail(path, key, f"must be a number in [{lo:g}, {hi:g}], got {v!r}")
    return float(v)


def _strings(v: Any, path: Path, key: str, *, required: bool = True) -> tuple[str, ...]:
    if v is None and not required:
        return ()
    if not isinstance(v, list) or not v or not all(isinstance(x, str) and x.strip() for x in v):
        raise _fail(path, key, "must be a non-empty list of non-empty strings")
    if len(set(v)) != len(v):
        dup = next(x for x in v if v.count(x) > 1)
        raise _fail(path, key, f"lists {dup!r} twice")
    return tuple(v)


def _condition(raw: Any, path: Path, k: int) -> Condition:
    key = f"condition #{k + 1}"
    if not isinstance(raw, dict):
        raise _fail(path, key, "must be a table ([[condition]])")
    _take(raw, path, key, {"name", "face", "table", "emotion", "intensity", "answer", "reference", "anchor"})
    name = _str(raw.get("name"), path, f"{key}.name")
    if not _NAME.fullmatch(name):
        raise _fail(path, f"{key}.name", f"{name!r} must be one word (letters, digits, _ . -)")
    table = raw.get("table")
    if table is not None:
        table_path = Path(_str(table, path, f"{key}.table"))
        table = table_path if table_path.is_absolute() else path.parent / table_path
        if not table.is_file():
            raise _fail(path, f"{key}.table", f"no such table file {table}")
    intensity = raw.get("intensity")
    if intensity is not None:
        intensity = _float(intensity, path, f"{key}.intensity", 0.0, 1.0)
    flags = {}
    for flag in ("reference", "anchor"):
        v = raw.get(flag, False)
        if not isinstance(v, bool):
            raise _fail(path, f"{key}.{flag}", f"must be true or false, got {v!r}")
        flags[flag] = v
    emotion = raw.get("emotion")
    return Condition(name=name, face=_choice(raw.get("face"), path, f"{key}.face", FACES, "model"), table=table,
                     emotion=None if emotion is None else _str(emotion, path, f"{key}.emotion"),
                     intensity=intensity, answer=None if raw.get("answer") is None else _str(raw["answer"], path, f"{key}.answer"),
                     **flags)


def vcv_consonant(item: str) -> str | None:
    """The consonant of a VCV item ("aba" → "b", "atsa" → "ts"), None for anything else."""
    m = _VCV.fullmatch(item.strip())
    return m.group(2) if m else None


def read_study(path: str | Path) -> StudySpec:
    """Read and check a study spec; SpecError naming the file and the key on any problem."""
    path = Path(path)
    try:
        doc = tomllib.loads(read_text(path, "study spec"))
    except FileNotFoundError:
        raise _fail(path, None, "no such study spec") from None
    except IsADirectoryError:
        raise _fail(path, None, "is a directory, not a study spec (.toml)") from None
    except TextDecodeError as e:
        raise SpecError(str(e)) from None
    except tomllib.TOMLDecodeError as e:
        raise _fail(path, None, f"not valid TOML: {e}") from None
    return parse_study(doc, path)


def parse_study(doc: dict[str, Any], path: Path) -> StudySpec:
    """A StudySpec from a parsed TOML document (see the module docstring for the keys)."""
    _take(doc, path, "top level", {"study", "stimuli", "condition"})
    study = doc.get("study")
    stim = doc.get("stimuli")
    if not isinstance(study, dict):
        raise _fail(path, "study", "the [study] table is required")
    if not isinstance(stim, dict):
        raise _fail(path, "stimuli", "the [stimuli] table is required")
    _take(study, path, "study", {"name", "design", "seed", "title", "consent", "instructions", "question",
                                 "attention_every", "counterbalance", "replay", "completion_code"})
    _take(stim, path, "stimuli", {"items", "answers", "response", "snr_db", "noise", "lang", "fps", "size_px",
                                  "choices", "render"})
    name = _str(study.get("name"), path, "study.name")
    if not _NAME.fullmatch(name):
        raise _fail(path, "study.name", f"{name!r} must be one word (letters, digits, _ . -), at most 64 characters")
    design = _choice(study.get("design"), path, "study.design", DESIGNS)
    seed = _int(study.get("seed"), path, "study.seed", -1, 0, 2**63 - 1)
    if seed < 0:
        raise _fail(path, "study.seed", "is required: every participant's randomisation derives from it")
    raw_conditions = doc.get("condition")
    if not isinstance(raw_conditions, list) or not raw_conditions:
        raise _fail(path, "condition", "at least one [[condition]] is required")
    conditions = tuple(_condition(c, path, k) for k, c in enumerate(raw_conditions))
    names = [c.name for c in conditions]
    for k, n in enumerate(names):
        if names.index(n) != k:
            raise _fail(path, f"condition #{k + 1}.name", f"{n!r} names condition #{names.index(n) + 1} already")
    items = _strings(stim.get("items"), path, "stimuli.items")
    response = _choice(stim.get("response"), path, "stimuli.response", RESPONSES, "choice")
    raw_snr = stim.get("snr_db")
    if raw_snr is None:
        if design == "intelligibility":
            raise _fail(path, "stimuli.snr_db", "is required for intelligibility: the SNRs (dB) at which noise is "
                        "mixed into the sound, e.g. [-6.0, 0.0]")
        snr: tuple[float | None, ...] = (None,)
    else:
        if not isinstance(raw_snr, list) or not raw_snr:
            raise _fail(path, "stimuli.snr_db", "must be a non-empty list of numbers (dB)")
        snr = tuple(_float(v, path, f"stimuli.snr_db[{i}]", -40.0, 60.0) for i, v in enumerate(raw_snr))
        if len(set(snr)) != len(snr):
            raise _fail(path, "stimuli.snr_db", "lists an SNR twice")
    answers: tuple[str, ...]
    if design == "intelligibility":
        if stim.get("answers") is not None:
            answers = _strings(stim.get("answers"), path, "stimuli.answers") if response == "choice" else tuple(stim["answers"])
            if len(answers) != len(items):
                raise _fail(path, "stimuli.answers", f"has {len(answers)} answers for {len(items)} items")
        elif response == "text":
            answers = items
        else:
            derived = [vcv_consonant(i) for i in items]
            if None in derived:
                bad = items[derived.index(None)]
                raise _fail(path, "stimuli.answers", f"is required: item {bad!r} is not a VCV (vowel, consonant(s), "
                            "the same vowel) whose consonant would be the answer")
            answers = tuple(d for d in derived if d is not None)
            if len(set(answers)) != len(answers):
                raise _fail(path, "stimuli.items", "two VCV items have the same consonant: give stimuli.answers")
    else:
        if stim.get("answers") is not None:
            raise _fail(path, "stimuli.answers", f"is for the intelligibility design, not {design}")
        answers = ()
    if design != "intelligibility" and response != "choice":
        raise _fail(path, "stimuli.response", f"{response!r} is for the intelligibility design")
    if design == "emotion":
        for k, c in enumerate(conditions):
            if (c.answer or c.emotion) is None:
                raise _fail(path, f"condition #{k + 1}", "an emotion study needs each condition's emotion "
                            "(emotion = \"joy\") or the answer it stands for (answer = \"joy\")")
    if design == "preference" and len(conditions) < 2:
        raise _fail(path, "condition", "a preference study compares at least two conditions")
    if design == "mushra":
        refs = [k for k, c in enumerate(conditions) if c.reference]
        if len(refs) != 1:
            raise _fail(path, "condition", f"a MUSHRA study needs exactly one condition with reference = true, got {len(refs)}")
        if len(conditions) < 2:
            raise _fail(path, "condition", "a MUSHRA study rates at least the reference and one other condition")
    else:
        for k, c in enumerate(conditions):
            if c.reference or c.anchor:
                raise _fail(path, f"condition #{k + 1}", f"reference/anchor are for the mushra design, not {design}")
    choices = _strings(stim.get("choices"), path, "stimuli.choices", required=False)
    lang = _choice(stim.get("lang"), path, "stimuli.lang", ("it", "en"), "it")
    fps = _float(stim.get("fps", 25.0), path, "stimuli.fps", 5.0, 120.0)
    spec = StudySpec(
        path=path, name=name, design=design, seed=seed,
        title=_str(study.get("title"), path, "study.title", name),
        consent=_str(study.get("consent"), path, "study.consent"),
        instructions=_str(study.get("instructions"), path, "study.instructions", ""),
        question=_str(study.get("question"), path, "study.question", DEFAULT_QUESTIONS[design]),
        items=items, answers=answers, conditions=conditions, response=response, snr_db=snr,
        noise=_choice(stim.get("noise"), path, "stimuli.noise", NOISES, "speech-shaped"), lang=lang, fps=fps,
        size_px=_int(stim.get("size_px"), path, "stimuli.size_px", 240, 64, 1024),
        render=_choice(stim.get("render"), path, "stimuli.render", RENDERS, "3d"),
        attention_every=_int(study.get("attention_every"), path, "study.attention_every", 8, 0, 1000),
        counterbalance=_choice(study.get("counterbalance"), path, "study.counterbalance", COUNTERBALANCE, "full"),
        replay=bool(study.get("replay", design != "intelligibility")),
        choices=choices,
        completion_code=_str(study.get("completion_code"), path, "study.completion_code", ""),
    )
    if spec.counterbalance == "latin" and design not in ("intelligibility", "emotion"):
        raise _fail(path, "study.counterbalance", f"latin rotates one condition per item: for intelligibility and "
                    f"emotion studies, not {design}")
    if spec.n_stimuli() > MAX_STIMULI:
        raise _fail(path, "stimuli", f"{len(items)} items x {len(conditions)} conditions x {len(snr)} SNRs = "
                    f"{spec.n_stimuli()} videos, more than {MAX_STIMULI}")
    return spec


DEFAULT_QUESTIONS = {
    "intelligibility": "What did the face say?",
    "emotion": "Which emotion did the face show?",
    "preference": "Which face speaks more naturally?",
    "mushra": "Rate how natural each face speaks (0 bad, 100 excellent).",
}
