"""The ground-truth parameter tables of the synthetic session, with the reason for every value.

Run it to (re)write ``ground_truth.json`` (the default session: vowels /i a u/) and
``ground_truth_italian.json`` (``--flavour italian``: all seven Italian vowels) next to this file::

    python corpus-synthetic/ground_truth.py

The values are written here as phonetic rules (rest posture, vowel specifications, consonant
classes with per-phoneme adjustments) rather than typed into the JSON by hand, so that every number
carries the rule that chose it as its ``reasons`` entry, and a change of rule changes every phoneme
it covers. Units: mm for every channel (MODEL.md §6 head frame: ULP/LLP are the lips' anterior
distance from the ear midpoint, LR the lip-corner distance, JO the nose-chin distance).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from coartic.table import CHANNELS, PARAMETERS, PAUSE, TONGUE_CHANNELS, ChannelSettings, ParameterTable

HERE = Path(__file__).resolve().parent
OUT = HERE / "ground_truth.json"
OUT_ITALIAN = HERE / "ground_truth_italian.json"

VOWELS = ("i", "a", "u")
# The seven vowels of standard Italian (docs/ARCHITECTURE.md phone set): close, close-mid and
# open-mid front vowels, open /a/, open-mid, close-mid and close rounded back vowels.
ITALIAN_VOWELS = ("i", "e", "E", "a", "O", "o", "u")
CONSONANTS = (
    "p b m f v t d n l r s z ts dz tS dZ S k g J L".split()
)
# The Italian flavour also has the semivowels /j w/ ("ieri", "uomo"), so that ordinary Italian text
# needs no fallback (Festival's Italian voice writes them as phones of their own).
SEMIVOWELS = ("j", "w")
REFERENCE = "a"

# The rest posture (the pause target): lips lightly together at the rest line (ULO = LLO = 0 by
# the definition of y_0), upper lip ~3 mm ahead of the lower lip, a neutral mouth width and the
# jaw at its rest distance. Every other target below is this rest plus a phonetic displacement.
REST = {"ULO": 0.0, "LLO": 0.0, "ULP": 98.0, "LLP": 95.0, "LR": 50.0, "JO": 115.0} | {ch: 0.0 for ch in TONGUE_CHANNELS}
REST_WHY = {
    "ULO": "rest posture: the upper lip at the rest line, which defines y_0",
    "LLO": "rest posture: the lower lip at the rest line, which defines y_0",
    "ULP": "rest posture: upper-lip vermilion ~98 mm ahead of the ear midpoint",
    "LLP": "rest posture: lower lip ~3 mm behind the upper lip",
    "LR": "rest posture: neutral mouth width 50 mm",
    "JO": "rest posture: nose-chin distance 115 mm with the teeth lightly apart",
    "TTH": "rest posture: the tongue tip at its rest height, which the channel is measured from (docs/DATA.md)",
    "TTA": "rest posture: the tongue tip at its rest advancement, which the channel is measured from",
    "TBH": "rest posture: the tongue body at its rest height, which the channel is measured from",
    "TBA": "rest posture: the tongue body at its rest advancement, which the channel is measured from",
}

# Plausible ranges for the fitter (targets only; the other parameters keep the default bounds).
TARGET_BOUNDS = {
    "ULO": (-8.0, 12.0),
    "LLO": (-8.0, 25.0),
    "ULP": (85.0, 112.0),
    "LLP": (82.0, 110.0),
    "LR": (35.0, 65.0),
    "JO": (100.0, 140.0),
} | {ch: (-25.0, 25.0) for ch in TONGUE_CHANNELS}

DEFAULTS: dict[str, tuple[float, str]] = {
    "c_bw": (1.0, "c = 1, the original model's activation exponent; nothing asks for another shape"),
    "c_fw": (1.0, "c = 1, the original model's activation exponent; nothing asks for another shape"),
    "sigma": (0.0, "sigma = 0: no shape bend is needed for this gesture"),
    "psi": (500.0, "psi is inactive while sigma = 0; a mid-range rate (width ~45 ms) as a neutral start"),
    "delta": (0.0, "no lag: the target is aimed at the acoustic segment's midpoint"),
}


@dataclass
class Spec:
    """Parameters of one phoneme on one channel, each with its reason."""

    values: dict[str, float] = field(default_factory=dict)
    reasons: dict[str, str] = field(default_factory=dict)

    def set(self, why: str, **kv: float) -> Spec:
        for name, value in kv.items():
            assert name in PARAMETERS, name
            self.values[name] = float(value)
            self.reasons[name] = why
        return self

    def complete(self) -> Spec:
        for name, (value, why) in DEFAULTS.items():
            if name not in self.values:
                self.set(why, **{name: value})
        missing = [p for p in PARAMETERS if p not in self.values]
        assert not missing, missing
        return self


Table = dict[str, dict[str, Spec]]


def pause(table: Table, channels: tuple[str, ...] = CHANNELS) -> None:
    for ch in channels:
        s = Spec()
        s.set(REST_WHY[ch], target=REST[ch])
        s.set("the rest posture dominates the pause (alpha at the top of the range, 3): the speaker "
              "holds still until just before the first vowel", alpha=3.0)
        s.set("rest is a slow posture: long reach (1/theta ~ 65 ms) into the first vowel's onset",
              theta_bw=15.0)
        s.set("rest is a slow posture: long forward reach (1/theta = 100 ms), so the anticipation of the "
              "first vowel starts late in the pause", theta_fw=10.0)
        s.set("k_R = 1: the speaker starts from and returns to rest, so the rest is reached", k_r=1.0)
        s.set(
            "the rest is aimed 75 ms after the pause midpoint: a long acoustic pause ends with the "
            "anticipation of the first vowel, so the rest is held through most of the pause (with "
            "k_R = 1 the channel is exactly at rest up to this time; the first pause defines y_0)",
            delta=0.075,
        )
        table[PAUSE][ch] = s


# The literature the Italian vowel postures follow (corpus-synthetic/README.md, docs/DATA.md):
#   [MC95] Magno Caldognetto, Vagges & Zmarich (1995), Visible articulatory characteristics of the
#          Italian stressed and unstressed vowels, ICPhS 95 (Stockholm), vol. 1, 366-369;
#   [MC98] Magno Caldognetto, Zmarich & Cosi (1998), Statistical definition of visual information
#          for Italian vowels and consonants, AVSP'98 (Terrigal), 135-140;
#   [FA99] Farnetani (1999), Labial coarticulation, in Hardcastle & Hewlett (eds), Coarticulation:
#          theory, data and techniques, CUP, 144-163;
#   [CA92] Canepari (1992), Manuale di pronuncia italiana, Zanichelli (lip and jaw settings of the
#          seven vowels);
#   [LS71] Lindblom & Sundberg (1971), Acoustical consequences of lip, tongue, jaw and larynx
#          movement, JASA 50, 1166-1179 (jaw opening grows with vowel openness).
# What they give is the ordering and the rough proportions (ELITE measurements of one or a few
# speakers: lip opening /a/ > /E/ > /O/ > /e/ > /o/ > /i/ > /u/; mouth width /i/ > /e/ > /E/ > /a/ >
# /O/ > /o/ > /u/; protrusion /u/ > /o/ > /O/, the front vowels retracted); the millimetres below are
# placed on that ordering between the values of /i a u/ of the default session, not copied from a
# table of those papers.
VOWEL_TARGETS: dict[str, dict[str, float]] = {
    "a": {"ULO": 2.5, "LLO": 12.0, "ULP": 97.5, "LLP": 94.0, "LR": 52.0, "JO": 125.0},
    "i": {"ULO": 1.5, "LLO": 5.0, "ULP": 96.5, "LLP": 93.5, "LR": 55.0, "JO": 117.0},
    "u": {"ULO": 0.5, "LLO": 3.5, "ULP": 101.0, "LLP": 98.0, "LR": 45.0, "JO": 116.5},
    "e": {"ULO": 2.0, "LLO": 7.5, "ULP": 96.8, "LLP": 93.6, "LR": 54.0, "JO": 119.5},
    "E": {"ULO": 2.3, "LLO": 10.0, "ULP": 97.2, "LLP": 93.8, "LR": 53.0, "JO": 122.5},
    "O": {"ULO": 1.5, "LLO": 8.5, "ULP": 99.5, "LLP": 96.5, "LR": 47.5, "JO": 121.5},
    "o": {"ULO": 1.0, "LLO": 5.5, "ULP": 100.3, "LLP": 97.3, "LR": 46.0, "JO": 118.5},
}
VOWEL_WHY: dict[tuple[str, str], str] = {
    ("a", "ULO"): "open vowel: the upper lip lifts a little with the open mouth",
    ("a", "LLO"): "open vowel: the largest lower-lip opening, the lip rides on the lowered jaw (~12 mm)",
    ("a", "ULP"): "open vowel: lips neither rounded nor spread, slightly drawn back by the open jaw",
    ("a", "LLP"): "open vowel: the lowered jaw pulls the lower lip back ~1 mm",
    ("a", "LR"): "open vowel: the open mouth widens a little (+2 mm)",
    ("a", "JO"): "open vowel: the jaw lowers ~10 mm",
    ("i", "ULO"): "close front vowel: the spread lips part a little",
    ("i", "LLO"): "close front vowel: small opening (jaw high), larger than /u/ because unrounded",
    ("i", "ULP"): "spread vowel: the upper lip is retracted ~1.5 mm",
    ("i", "LLP"): "spread vowel: the lower lip is retracted ~1.5 mm",
    ("i", "LR"): "spread vowel: the widest mouth (+5 mm)",
    ("i", "JO"): "close vowel: the jaw nearly at rest (+2 mm)",
    ("u", "ULO"): "rounded close vowel: the narrow rounded opening hardly lifts the upper lip",
    ("u", "LLO"): "rounded close vowel: the smallest vowel opening",
    ("u", "ULP"): "rounded vowel: the upper lip protrudes ~3 mm",
    ("u", "LLP"): "rounded vowel: the lower lip protrudes ~3 mm",
    ("u", "LR"): "rounded vowel: the narrowest mouth (-5 mm)",
    ("u", "JO"): "close vowel: the jaw nearly at rest (+1.5 mm)",
    ("e", "ULO"): "close-mid front vowel: the upper lip lifts between /i/ and /E/ [MC95, MC98]",
    ("e", "LLO"): "close-mid front vowel: lip opening above /i/ and /o/, below /O/ (7.5 mm) [MC95, MC98]",
    ("e", "ULP"): "unrounded front vowel: the upper lip retracted, less than for /i/ (-1.2 mm) [MC98, CA92]",
    ("e", "LLP"): "unrounded front vowel: the lower lip retracted, less than for /i/ [MC98, CA92]",
    ("e", "LR"): "spread front vowel: mouth width second only to /i/ (+4 mm) [MC98, CA92]",
    ("e", "JO"): "close-mid vowel: the jaw a step lower than for /i/ (+4.5 mm) [LS71, CA92]",
    ("E", "ULO"): "open-mid front vowel: the upper lip lifts almost as for /a/ [MC95, MC98]",
    ("E", "LLO"): "open-mid front vowel: the largest opening after /a/ (10 mm) [MC95, MC98]",
    ("E", "ULP"): "unrounded front vowel: the upper lip slightly retracted, nearer rest than /e/ [MC98]",
    ("E", "LLP"): "unrounded front vowel: the lower lip slightly retracted, the open jaw draws it back [MC98]",
    ("E", "LR"): "front vowel, mildly spread: wider than /a/, narrower than /e/ (+3 mm) [MC98, CA92]",
    ("E", "JO"): "open-mid vowel: the jaw between /e/ and /a/ (+7.5 mm) [LS71, CA92]",
    ("O", "ULO"): "open-mid rounded vowel: rounding keeps the upper lip lower than for /E/ [MC95, MC98]",
    ("O", "LLO"): "open-mid back vowel: opening below /E/ (rounding narrows it), above /e/ (8.5 mm) [MC95, MC98]",
    ("O", "ULP"): "open-mid rounded vowel: the least protruded of the rounded vowels (+1.5 mm) [MC98, FA99]",
    ("O", "LLP"): "open-mid rounded vowel: the lower lip protrudes +1.5 mm [MC98, FA99]",
    ("O", "LR"): "open-mid rounded vowel: narrower than rest, wider than /o u/ (-2.5 mm) [MC98, CA92]",
    ("O", "JO"): "open-mid vowel: the jaw about as low as for /E/, a little higher (+6.5 mm) [LS71, CA92]",
    ("o", "ULO"): "close-mid rounded vowel: a small rounded opening [MC95, MC98]",
    ("o", "LLO"): "close-mid rounded vowel: opening between /u/ and /e/ (5.5 mm) [MC95, MC98]",
    ("o", "ULP"): "close-mid rounded vowel: protruded, nearly as much as /u/ (+2.3 mm) [MC98, FA99]",
    ("o", "LLP"): "close-mid rounded vowel: the lower lip protrudes +2.3 mm [MC98, FA99]",
    ("o", "LR"): "close-mid rounded vowel: narrow, 1 mm wider than /u/ (-4 mm) [MC98, CA92]",
    ("o", "JO"): "close-mid vowel: the jaw as for /e/, a little higher (+3.5 mm) [LS71, CA92]",
}


def vowels(table: Table, vowel_set: tuple[str, ...] = VOWELS) -> None:
    # Targets: open /a/ > /i/ > /u/ in lip and jaw opening; /i/ spread (wide, retracted),
    # /u/ rounded (narrow, protruded); the mid vowels of Italian between them (VOWEL_TARGETS).
    for v in vowel_set:
        for ch in CHANNELS:
            s = Spec().set(VOWEL_WHY[(v, ch)], target=VOWEL_TARGETS[v][ch])
            s.set("vowels are the long, dominant gestures of a VCV: long reach (1/theta = 50 ms)",
                  theta_bw=20.0, theta_fw=20.0)
            s.set("vowels yield to neighbouring consonants (moderate resistance)", k_r=0.4)
            if v == REFERENCE:
                s.set("reference phoneme: alpha fixed to 1 on every channel (the scale of dominance)", alpha=1.0)
            else:
                s.set("a vowel is about as dominant as the reference /a/", alpha=1.0)
            table[v][ch] = s
    # Rounding and spreading: the lip-shape vowels dominate the lip-shape channels.
    for ch in ("ULP", "LLP", "LR"):
        u = table["u"][ch]
        u.set("rounding is the defining gesture of /u/: it dominates the lip-shape channels", alpha=2.0)
        u.set("anticipatory rounding reaches far back into the consonant (1/theta ~ 80 ms)", theta_bw=12.0)
        u.set("anticipatory rounding: the rounding target is aimed 20 ms before the acoustic midpoint",
              delta=-0.02)
        u.set("rounding resists the consonant's lip shape", k_r=0.5)
    table["i"]["LR"].set("spreading is the defining gesture of /i/ on mouth width", alpha=1.5)
    table["i"]["LR"].set("spreading resists the consonant's lip shape", k_r=0.5)
    for ch in ("ULP", "LLP"):
        table["i"][ch].set("lip retraction goes with spreading, somewhat dominant", alpha=1.2)
    table["u"]["LR"].set("rounding closes in with a sharper (c > 1) activation than it releases", c_bw=1.2)
    a = table["a"]["LLO"]
    a.set("the jaw-lip opening of /a/ peaks at the nucleus: 8 % overshoot at the target time", sigma=0.08)
    a.set("the overshoot lasts about the vowel nucleus (1/sqrt(psi) = 50 ms)", psi=400.0)
    if "o" in vowel_set:
        mid_vowels(table)


def mid_vowels(table: Table) -> None:
    """The dynamics of the Italian mid vowels /e E O o/: graded between /a/ and /i u/."""
    # Rounding: Italian /o/ is rounded and protruded almost like /u/, /O/ less [MC98, FA99]; their
    # anticipation into a preceding consonant is graded the same way (Farnetani's Italian data:
    # anticipatory rounding starts within the consonant, later for the less rounded vowel).
    for v, alpha, theta, delta, k_r in (("o", 1.7, 14.0, -0.015, 0.45), ("O", 1.4, 16.0, -0.01, 0.4)):
        for ch in ("ULP", "LLP", "LR"):
            s = table[v][ch]
            s.set(f"rounding defines /{v}/ too, less than /u/: dominant on the lip-shape channels [MC98, FA99]",
                  alpha=alpha)
            s.set(f"anticipatory rounding of /{v}/ reaches back into the consonant, less far than /u/'s "
                  f"(1/theta ~ {1000 / theta:.0f} ms) [FA99]", theta_bw=theta)
            s.set(f"anticipatory rounding: the target of /{v}/ is aimed {-delta * 1000:.0f} ms before the "
                  "acoustic midpoint, less early than /u/ [FA99]", delta=delta)
            s.set(f"the rounding of /{v}/ resists the consonant's lip shape, less than /u/", k_r=k_r)
    # Spreading: /e/ spread less than /i/, /E/ barely [MC98, CA92].
    table["e"]["LR"].set("spreading defines /e/ less than /i/: somewhat dominant on mouth width [MC98]", alpha=1.3)
    table["e"]["LR"].set("the spreading of /e/ resists the consonant's lip shape a little", k_r=0.45)
    table["E"]["LR"].set("/E/ is only mildly spread: a little more dominant than /a/ on mouth width [MC98]",
                         alpha=1.1)
    for ch in ("ULP", "LLP"):
        table["e"][ch].set("lip retraction goes with spreading, less than for /i/", alpha=1.1)


# Consonant classes: displacement from the rest posture per channel, dominance per channel, and the
# class-wide dynamics. Per-phoneme adjustments follow below.
@dataclass
class Cls:
    name: str
    members: tuple[str, ...]
    target: dict[str, tuple[float, str]]
    alpha: dict[str, tuple[float, str]]
    theta: tuple[float, str]
    k_r: dict[str, tuple[float, str]]


WEAK_LIPS = "lips are free for this consonant: weak dominance, the vowel context shapes them"


def consonant_classes() -> list[Cls]:
    return [
        Cls(
            "bilabial stop/nasal",
            ("p", "b", "m"),
            target={
                "ULO": (-2.0, "bilabial closure: the upper lip presses down past the rest line (lip compression)"),
                "LLO": (-2.5, "bilabial closure: the lower lip presses up past the rest line; the aperture closes"),
                "ULP": (98.3, "bilabial closure pushes the upper lip slightly forward (+0.3 mm)"),
                "LLP": (95.5, "bilabial closure pushes the lower lip slightly forward (+0.5 mm)"),
                "LR": (49.5, "bilabial closure: lips neutral, marginally narrower while compressed"),
                "JO": (116.0, "the jaw rises for the closure but the lips do most of the work"),
            },
            alpha={
                "ULO": (2.5, "the closure is the consonant's goal: strongly dominant on lip opening"),
                "LLO": (2.5, "the closure is the consonant's goal: strongly dominant on lip opening"),
                "ULP": (0.7, WEAK_LIPS),
                "LLP": (0.7, WEAK_LIPS),
                "LR": (0.6, WEAK_LIPS),
                "JO": (1.0, "the jaw supports the closure as much as a vowel moves it"),
            },
            theta=(40.0, "a consonant gesture: shorter reach than a vowel (1/theta = 25 ms)"),
            k_r={
                "ULO": (1.0, "k_R = 1: bilabial closure is always reached, at any rate (Cosi & Perin)"),
                "LLO": (1.0, "k_R = 1: bilabial closure is always reached, at any rate (Cosi & Perin)"),
                "ULP": (0.3, "protrusion is not critical for a bilabial: low resistance"),
                "LLP": (0.3, "protrusion is not critical for a bilabial: low resistance"),
                "LR": (0.3, "width is not critical for a bilabial: low resistance"),
                "JO": (0.5, "the jaw position is loosely constrained by the closure"),
            },
        ),
        Cls(
            "labiodental fricative",
            ("f", "v"),
            target={
                "ULO": (0.8, "labiodental: the upper lip lifts clear of the lower lip-teeth contact"),
                "LLO": (-1.0, "labiodental: the lower lip is raised to the upper teeth (aperture small but open)"),
                "ULP": (98.2, "labiodental: the upper lip stays near rest"),
                "LLP": (92.5, "labiodental: the lower lip is retracted under the upper teeth (-2.5 mm)"),
                "LR": (50.5, "labiodental: the mouth is slightly widened"),
                "JO": (115.5, "the jaw is raised to bring the lower lip to the teeth"),
            },
            alpha={
                "ULO": (0.8, "the upper lip is not the articulator of /f v/: moderate dominance"),
                "LLO": (2.5, "the lip-teeth contact is the consonant's goal: strongly dominant"),
                "ULP": (0.7, WEAK_LIPS),
                "LLP": (2.5, "the lower-lip retraction is part of the contact: strongly dominant"),
                "LR": (0.7, WEAK_LIPS),
                "JO": (1.2, "the jaw must be high for the contact"),
            },
            theta=(40.0, "a consonant gesture: shorter reach than a vowel (1/theta = 25 ms)"),
            k_r={
                "ULO": (0.5, "the upper lip is free: moderate resistance"),
                "LLO": (1.0, "k_R = 1: the labiodental contact is always reached, at any rate (Cosi & Perin)"),
                "ULP": (0.3, "not critical for /f v/: low resistance"),
                "LLP": (1.0, "k_R = 1: the lower lip must reach the teeth, so its retraction is always reached"),
                "LR": (0.3, "not critical for /f v/: low resistance"),
                "JO": (0.5, "the jaw is loosely constrained by the contact"),
            },
        ),
        Cls(
            "dental/alveolar stop/nasal",
            ("t", "d", "n"),
            target={
                "ULO": (1.0, "tongue-tip consonant: lips follow the raised jaw, slightly apart"),
                "LLO": (3.0, "tongue-tip consonant: the lower lip rides on the high jaw, small opening"),
                "ULP": (97.8, "tongue-tip consonant: lips near rest"),
                "LLP": (94.8, "tongue-tip consonant: lips near rest"),
                "LR": (51.0, "tongue-tip consonant: mouth width near rest"),
                "JO": (116.5, "tongue-tip closure needs a high jaw (+1.5 mm)"),
            },
            alpha={
                "ULO": (0.8, WEAK_LIPS),
                "LLO": (0.8, WEAK_LIPS),
                "ULP": (0.7, WEAK_LIPS),
                "LLP": (0.7, WEAK_LIPS),
                "LR": (0.7, WEAK_LIPS),
                "JO": (1.5, "the jaw carries the tongue tip to the alveolar ridge: dominant on jaw opening"),
            },
            theta=(45.0, "a short consonant gesture (1/theta = 22 ms)"),
            k_r={ch: (0.3, "the lips are free: low resistance") for ch in ("ULO", "LLO", "ULP", "LLP", "LR")}
            | {"JO": (0.6, "the jaw height matters for the tongue-tip closure")},
        ),
        Cls(
            "liquid",
            ("l", "r"),
            target={
                "ULO": (1.2, "liquid: lips follow the jaw, slightly apart"),
                "LLO": (3.5, "liquid: the jaw is less raised than for a stop, a little more opening"),
                "ULP": (97.8, "liquid: lips near rest"),
                "LLP": (94.8, "liquid: lips near rest"),
                "LR": (51.0, "liquid: mouth width near rest"),
                "JO": (117.5, "liquid: tongue-tip contact without full jaw raising (+2.5 mm)"),
            },
            alpha={
                "ULO": (0.8, WEAK_LIPS),
                "LLO": (0.8, WEAK_LIPS),
                "ULP": (0.8, WEAK_LIPS),
                "LLP": (0.8, WEAK_LIPS),
                "LR": (0.8, WEAK_LIPS),
                "JO": (1.2, "the jaw supports the tongue tip moderately"),
            },
            theta=(40.0, "a brief consonant gesture (1/theta = 25 ms)"),
            k_r={ch: (0.2, "a liquid hardly resists anything: low resistance") for ch in CHANNELS},
        ),
        Cls(
            "alveolar sibilant",
            ("s", "z", "ts", "dz"),
            target={
                "ULO": (1.2, "sibilant: the lips part slightly over the close teeth"),
                "LLO": (2.0, "sibilant: the jaw is high (teeth close), little lower-lip opening"),
                "ULP": (97.5, "alveolar sibilant: lips slightly spread, retracted 0.5 mm"),
                "LLP": (94.5, "alveolar sibilant: lips slightly spread, retracted 0.5 mm"),
                "LR": (51.5, "alveolar sibilant: the mouth is slightly spread"),
                "JO": (114.0, "sibilant: the jaw is highest (teeth close for the noise), above the rest"),
            },
            alpha={
                "ULO": (0.8, "the lips matter a little for the sibilant's noise"),
                "LLO": (0.8, "the lips matter a little for the sibilant's noise"),
                "ULP": (0.6, WEAK_LIPS),
                "LLP": (0.6, WEAK_LIPS),
                "LR": (0.8, "the slight spreading matters a little for the noise"),
                "JO": (2.5, "the close teeth are required for the noise: jaw strongly dominant"),
            },
            theta=(40.0, "a consonant gesture: shorter reach than a vowel (1/theta = 25 ms)"),
            k_r={ch: (0.3, "the lips are free: low resistance") for ch in ("ULO", "LLO", "ULP", "LLP", "LR")}
            | {"JO": (0.8, "the jaw must close the teeth for the noise: high resistance")},
        ),
        Cls(
            "postalveolar (rounded)",
            ("S", "tS", "dZ"),
            target={
                "ULO": (2.0, "postalveolar: the everted upper lip lifts"),
                "LLO": (2.5, "postalveolar: the everted lower lip opens a little"),
                "ULP": (100.5, "postalveolar: the lips protrude (+2.5 mm), as Italian /S tS dZ/ are rounded"),
                "LLP": (97.5, "postalveolar: the lips protrude (+2.5 mm), as Italian /S tS dZ/ are rounded"),
                "LR": (46.0, "postalveolar: rounded, a narrow mouth (-4 mm)"),
                "JO": (114.5, "postalveolar: high jaw for the noise"),
            },
            alpha={
                "ULO": (1.2, "the eversion is part of the sound"),
                "LLO": (1.0, "the eversion is part of the sound"),
                "ULP": (2.0, "protrusion is part of the sound: dominant"),
                "LLP": (2.0, "protrusion is part of the sound: dominant"),
                "LR": (1.5, "rounding is part of the sound"),
                "JO": (2.0, "close teeth for the noise: dominant"),
            },
            theta=(35.0, "a long consonant gesture (1/theta ~ 29 ms)"),
            k_r={
                "ULO": (0.4, "the lip opening is loosely constrained"),
                "LLO": (0.4, "the lip opening is loosely constrained"),
                "ULP": (0.7, "protrusion resists the vowel context"),
                "LLP": (0.7, "protrusion resists the vowel context"),
                "LR": (0.6, "rounding resists the vowel context"),
                "JO": (0.7, "the jaw must stay high for the noise"),
            },
        ),
        Cls(
            "velar stop",
            ("k", "g"),
            target={
                "ULO": (1.2, "velar: the lips are free, slightly apart"),
                "LLO": (3.5, "velar: the jaw is lower than for front consonants"),
                "ULP": (97.8, "velar: lips near rest"),
                "LLP": (94.8, "velar: lips near rest"),
                "LR": (50.5, "velar: mouth width near rest"),
                "JO": (117.5, "velar: the tongue back closes with the jaw moderately raised (+2.5 mm)"),
            },
            alpha={
                "ULO": (0.7, WEAK_LIPS),
                "LLO": (0.7, WEAK_LIPS),
                "ULP": (0.7, WEAK_LIPS),
                "LLP": (0.7, WEAK_LIPS),
                "LR": (0.7, WEAK_LIPS),
                "JO": (1.0, "the jaw supports the tongue back moderately"),
            },
            theta=(45.0, "a short consonant gesture (1/theta = 22 ms)"),
            k_r={ch: (0.3, "the lips are free: low resistance") for ch in ("ULO", "LLO", "ULP", "LLP", "LR")}
            | {"JO": (0.4, "the jaw is loosely constrained")},
        ),
        Cls(
            "palatal",
            ("J", "L"),
            target={
                "ULO": (1.0, "palatal: lips follow the high jaw, slightly apart"),
                "LLO": (2.5, "palatal: the tongue body against the palate keeps the jaw high"),
                "ULP": (97.6, "palatal: lips slightly spread"),
                "LLP": (94.6, "palatal: lips slightly spread"),
                "LR": (51.5, "palatal: the front tongue gesture spreads the mouth slightly"),
                "JO": (116.0, "palatal: high jaw (+1 mm)"),
            },
            alpha={
                "ULO": (0.7, WEAK_LIPS),
                "LLO": (0.7, "the high jaw carries the lower lip"),
                "ULP": (0.7, WEAK_LIPS),
                "LLP": (0.7, WEAK_LIPS),
                "LR": (0.7, "slight spreading, weakly specified"),
                "JO": (1.5, "the tongue-body contact needs a high jaw"),
            },
            theta=(30.0, "Italian /J L/ are long (geminate-like) consonants: longer reach (1/theta ~ 33 ms)"),
            k_r={ch: (0.3, "the lips are free: low resistance") for ch in ("ULO", "LLO", "ULP", "LLP", "LR")}
            | {"JO": (0.6, "the jaw height matters for the palatal contact")},
        ),
    ]


def semivowel_classes() -> list[Cls]:
    """/j w/ of the Italian flavour: the lips of /i/ and /u/, closer and briefer [CA92, FA99]."""
    return [
        Cls(
            "palatal approximant",
            ("j",),
            target={
                "ULO": (1.0, "the lips of /i/, a little closer: the tongue body is nearer the palate than for /i/ [CA92]"),
                "LLO": (3.0, "a closer /i/: small opening on a high jaw [CA92]"),
                "ULP": (96.5, "spread like /i/: the upper lip retracted ~1.5 mm [CA92]"),
                "LLP": (93.5, "spread like /i/: the lower lip retracted ~1.5 mm [CA92]"),
                "LR": (54.0, "spread like /i/, slightly less wide (+4 mm) [CA92]"),
                "JO": (116.0, "high jaw for the palatal approximant (+1 mm)"),
            },
            alpha={
                "ULO": (0.8, WEAK_LIPS),
                "LLO": (0.8, WEAK_LIPS),
                "ULP": (0.8, "retraction goes with the spreading, weakly"),
                "LLP": (0.8, "retraction goes with the spreading, weakly"),
                "LR": (1.0, "the spreading of /j/ is as dominant as a vowel's"),
                "JO": (1.2, "the tongue body near the palate needs a high jaw"),
            },
            theta=(35.0, "a glide: a brief gesture between consonant and vowel (1/theta ~ 29 ms)"),
            k_r={ch: (0.3, "a glide yields to its vowel context: low resistance") for ch in CHANNELS},
        ),
        Cls(
            "labial-velar approximant",
            ("w",),
            target={
                "ULO": (0.3, "the narrowest rounded opening: closer than /u/ [CA92, FA99]"),
                "LLO": (2.0, "the narrowest rounded opening: closer than /u/ [CA92, FA99]"),
                "ULP": (101.5, "protruded as much as /u/ or a little more (+3.5 mm) [FA99]"),
                "LLP": (98.5, "protruded as much as /u/ or a little more (+3.5 mm) [FA99]"),
                "LR": (43.5, "the narrowest mouth of all (-6.5 mm): a labial constriction [CA92, FA99]"),
                "JO": (116.0, "high jaw, as for /u/ (+1 mm)"),
            },
            alpha={
                "ULO": (1.2, "the labial constriction is part of /w/"),
                "LLO": (1.2, "the labial constriction is part of /w/"),
                "ULP": (2.0, "rounding is the defining gesture of /w/, as of /u/: dominant"),
                "LLP": (2.0, "rounding is the defining gesture of /w/, as of /u/: dominant"),
                "LR": (2.0, "rounding is the defining gesture of /w/, as of /u/: dominant"),
                "JO": (0.8, "the jaw is free for /w/"),
            },
            theta=(30.0, "a glide whose rounding is anticipated (1/theta ~ 33 ms) [FA99]"),
            k_r={ch: (0.6 if ch in ("ULP", "LLP", "LR") else 0.3,
                      "the rounding resists the vowel context" if ch in ("ULP", "LLP", "LR")
                      else "the opening yields to the vowel context")
                 for ch in CHANNELS},
        ),
    ]


def consonants(table: Table, semivowels: bool = False) -> None:
    for cls in consonant_classes() + (semivowel_classes() if semivowels else []):
        for c in cls.members:
            for ch in CHANNELS:
                s = Spec()
                s.set(f"{cls.name}: " + cls.target[ch][1], target=cls.target[ch][0])
                s.set(cls.alpha[ch][1], alpha=cls.alpha[ch][0])
                s.set(cls.theta[1], theta_bw=cls.theta[0], theta_fw=cls.theta[0])
                s.set(cls.k_r[ch][1], k_r=cls.k_r[ch][0])
                table[c][ch] = s
    # Per-phoneme adjustments within a class.
    adj = [
        ("b", "LLO", "voiced bilabial: slightly less compression than /p/", {"target": -2.3}),
        ("b", "ULO", "voiced bilabial: slightly less compression than /p/", {"target": -1.8}),
        ("m", "LLO", "nasal bilabial: the lightest compression (no oral pressure to hold)", {"target": -2.0}),
        ("m", "ULO", "nasal bilabial: the lightest compression (no oral pressure to hold)", {"target": -1.5}),
        ("p", "LLO", "voiceless bilabial: the compression peaks at mid-closure (15 % overshoot)", {"sigma": 0.15}),
        ("p", "LLO", "the compression peak is brief (1/sqrt(psi) ~ 29 ms)", {"psi": 1200.0}),
        ("p", "ULO", "closure gestures are abrupt: sharper activation and release (c > 1)",
         {"c_bw": 1.3, "c_fw": 1.3}),
        ("p", "LLO", "closure gestures are abrupt: sharper activation and release (c > 1)",
         {"c_bw": 1.3, "c_fw": 1.3}),
        ("b", "LLO", "closure gestures are abrupt: sharper activation and release (c > 1)",
         {"c_bw": 1.3, "c_fw": 1.3}),
        ("v", "LLO", "voiced labiodental: a looser contact than /f/", {"target": -0.8}),
        ("v", "LLP", "voiced labiodental: a little less retraction than /f/", {"target": 92.8}),
        ("d", "JO", "voiced stop: jaw slightly lower than /t/", {"target": 117.0}),
        ("n", "JO", "nasal: no oral pressure, jaw slightly lower than /t/", {"target": 117.0}),
        ("n", "LLO", "nasal: a little more opening than /t/", {"target": 3.3}),
        ("r", "LLO", "trill/tap: the tongue tip vibrates with a slightly open jaw", {"target": 4.0}),
        ("z", "JO", "voiced sibilant: the jaw a little less high than /s/", {"target": 114.5}),
        ("ts", "JO", "affricate: the stop phase needs the jaw slightly higher than /s/", {"target": 114.2}),
        ("dz", "JO", "voiced affricate: as /ts/, jaw a little lower", {"target": 114.7}),
        ("ts", "LLO", "affricate: the stop phase closes the teeth, less lip opening", {"target": 1.8}),
        ("S", "ULP", "fricative /S/ holds the longest protrusion and anticipates it (target 15 ms early)",
         {"delta": -0.015}),
        ("S", "ULP", "protrusion builds up with a sharper activation (c > 1)", {"c_bw": 1.2}),
        ("dZ", "ULP", "voiced affricate: a little less protrusion than /tS/", {"target": 100.2}),
        ("dZ", "LLP", "voiced affricate: a little less protrusion than /tS/", {"target": 97.2}),
        ("g", "JO", "voiced velar: jaw slightly lower than /k/", {"target": 118.0}),
        ("L", "LLO", "lateral palatal: the tongue sides lowered, a little more opening than /J/", {"target": 3.0}),
        ("L", "JO", "lateral palatal: jaw a little lower than /J/", {"target": 116.5}),
    ]
    for ph, ch, why, kv in adj:
        table[ph][ch].set(why, **kv)
    # A stop's release is quicker than its closing, so its forward rate is higher.
    for c in ("p", "b", "t", "d", "k", "g"):
        for ch in CHANNELS:
            s = table[c][ch]
            s.set("stop release is quicker than its closing: shorter forward reach",
                  theta_fw=s.values["theta_bw"] * 1.25)


# ----------------------------------------------------------------------------- Italian flavour only

# Rounding, Italian flavour. The default session keeps /u/ at 45 mm (its table is the one `make fit`
# recovers and the paper's /i a u/ corpus supports); the Italian flavour, whose table the package ships
# and the face shows, narrows its rounded sounds as the lip-rounding literature measures them:
#   [FR64] Fromkin (1964), Lip positions in American English vowels, Language and Speech 7, 215-225
#          (photographs and casts: the distance between the mouth corners is the lip dimension that
#          separates rounded from unrounded vowels most, /u/ the narrowest);
#   [LI82] Linker (1982), Articulatory and acoustic correlates of labial activity in vowels: a
#          cross-linguistic study, UCLA Working Papers in Phonetics 56 (horizontal lip width of
#          rounded vowels far below the spread and neutral ones in every language measured);
#   [MC95], [MC98] (above): the same ordering in ELITE's LR for the seven Italian vowels;
#   [CA92]: Italian /S tS dZ/ are said with protruded, rounded lips, less than /u/.
# The millimetres are placed on that ordering (not read off a table of those papers): /u/ a quarter
# narrower than rest, /o/ and /O/ graded between, /w/ a little narrower than /u/, /S tS dZ/ rounded
# about as /O/; so the face shows a rounded /u/ from the front (docs/FACE.md).
ITALIAN_LR: dict[str, tuple[float, str]] = {
    "u": (38.0, "rounded close vowel: the narrowest vowel, the corners drawn in a quarter of the rest "
                "width (-12 mm) [FR64, LI82, MC95, MC98]"),
    "o": (41.0, "close-mid rounded vowel: narrow, 3 mm wider than /u/ (-9 mm) [FR64, MC95, MC98]"),
    "O": (44.5, "open-mid rounded vowel: narrower than rest, wider than /o u/ (-5.5 mm) [MC95, MC98, CA92]"),
    "w": (37.0, "labial-velar approximant: the narrowest mouth of all, a closer /u/ (-13 mm) [CA92, FA99]"),
    "S": (45.0, "postalveolar: rounded with the protrusion, about as narrow as /O/ (-5 mm) [CA92, FA99]"),
    "tS": (45.0, "postalveolar: rounded with the protrusion, about as narrow as /O/ (-5 mm) [CA92, FA99]"),
    "dZ": (45.0, "postalveolar: rounded with the protrusion, about as narrow as /O/ (-5 mm) [CA92, FA99]"),
}


def italian_rounding(table: Table) -> None:
    for ph, (target, why) in ITALIAN_LR.items():
        table[ph]["LR"].set(why, target=target)


# The tongue, Italian flavour: the channels TTH TTA TBH TBA of docs/DATA.md (height and advancement
# of the tongue tip and body, mm from their rest position in the head frame, positive up and
# forwards), which the session writes as EMA sensor files. Places of articulation and what the
# tongue does at each, from:
#   [CA92]: Italian /t d n/ dental (laminal, the tip against the upper incisors), /l r s z ts dz/
#          alveolar (/r/ a trill), /S tS dZ/ postalveolar (the tip raised behind the ridge, the front
#          of the body raised), /J L/ palatal (the dorsum against the hard palate), /k g/ velar;
#   [FA90] Farnetani (1990), V-C-V lingual coarticulation and its spatiotemporal domain, in
#          Hardcastle & Marchal (eds), Speech production and speech modelling, Kluwer, 93-110
#          (Italian EPG: contact at the teeth-ridge for /t d n l/, palatal contact for /J L/, the
#          velar closure moving with the vowel);
#   [RE97] Recasens, Pallares & Fontdevila (1997), A model of lingual coarticulation based on
#          articulatory constraints, JASA 102, 544-561 (degree of articulatory constraint: palatals
#          and the dorsum of trills and sibilants resist coarticulation most, dentals and alveolars
#          on the tip, velars on the body height but not its advancement, labials least);
#   [LS71] (above): the tongue lowers with the jaw from close to open vowels.
# Sizes: the tip rises 7-9.5 mm from rest to a dental or alveolar closure and the body 11-11.5 mm to
# the velum or the palate; open /a/ takes both ~8-9 mm down with the jaw (10 mm lower here); front vowels
# advance the body, back vowels retract it. Like the lip millimetres, placed on those descriptions.
TONGUE_TARGETS: dict[str, tuple[tuple[float, float, float, float], str]] = {
    "i": ((2.0, 2.0, 8.0, 3.0), "close front vowel: the body high and forward, the tip behind the lower incisors"),
    "e": ((0.0, 1.5, 5.0, 2.0), "close-mid front vowel: the body raised and forward, less than for /i/"),
    "E": ((-3.0, 0.5, 1.0, 1.0), "open-mid front vowel: the body near rest, lowered with the jaw"),
    "a": ((-9.0, -1.5, -8.0, -2.0), "open vowel: the tongue lowered with the jaw, the body a little back"),
    "O": ((-6.0, -3.0, -3.0, -5.0), "open-mid back vowel: the body low and back"),
    "o": ((-3.5, -3.5, 1.0, -5.5), "close-mid back vowel: the body back, nearly at rest height"),
    "u": ((-2.0, -4.0, 5.0, -6.0), "close back vowel: the body raised towards the velum, the most retracted"),
    "p": ((-1.0, 0.0, -0.5, 0.0), "bilabial: the tongue is free, near rest, lowered a little with the jaw"),
    "b": ((-1.0, 0.0, -0.5, 0.0), "bilabial: the tongue is free, near rest, lowered a little with the jaw"),
    "m": ((-1.0, 0.0, -0.5, 0.0), "bilabial: the tongue is free, near rest, lowered a little with the jaw"),
    "f": ((-0.5, 0.0, -0.3, 0.0), "labiodental: the tongue is free, near rest"),
    "v": ((-0.5, 0.0, -0.3, 0.0), "labiodental: the tongue is free, near rest"),
    "t": ((9.0, 2.5, 2.0, 0.5), "dental stop: the tip up and forward to the upper incisors [CA92, FA90]"),
    "d": ((9.0, 2.5, 2.0, 0.5), "dental stop: the tip up and forward to the upper incisors [CA92, FA90]"),
    "n": ((8.5, 2.0, 2.0, 0.5), "dental nasal: the tip against the upper incisors, a little lower jaw [CA92, FA90]"),
    "l": ((9.5, 1.0, 0.5, -0.5), "alveolar lateral: the tip on the ridge, higher than for the dentals, the "
                                 "body lowered for the side channels [CA92, FA90]"),
    "r": ((7.5, 0.5, 1.0, -1.0), "alveolar trill: the tip raised at the ridge, the dorsum held back [CA92, RE97]"),
    "s": ((7.0, 1.5, 3.0, 0.5), "alveolar sibilant: the tip close to the ridge, grooved, the body raised "
                                "[CA92, RE97]"),
    "z": ((7.0, 1.5, 3.0, 0.5), "alveolar sibilant: the tip close to the ridge, grooved, the body raised "
                                "[CA92, RE97]"),
    "ts": ((8.5, 2.0, 3.0, 0.5), "alveolar affricate: the stop phase closes the tip at the ridge [CA92]"),
    "dz": ((8.5, 2.0, 3.0, 0.5), "alveolar affricate: the stop phase closes the tip at the ridge [CA92]"),
    "S": ((6.5, -2.0, 6.0, 0.0), "postalveolar fricative: the tip raised behind the ridge, the front of the "
                                 "body raised [CA92]"),
    "tS": ((7.0, -1.5, 6.0, 0.0), "postalveolar affricate: the tip closes behind the ridge, the body raised [CA92]"),
    "dZ": ((7.0, -1.5, 6.0, 0.0), "postalveolar affricate: the tip closes behind the ridge, the body raised [CA92]"),
    "k": ((-1.5, -2.0, 11.5, -3.0), "velar stop: the body closes against the velum, the tip down [CA92, FA90]"),
    "g": ((-1.5, -2.0, 11.5, -3.0), "velar stop: the body closes against the velum, the tip down [CA92, FA90]"),
    "J": ((3.0, 0.5, 11.0, 2.0), "palatal nasal: the dorsum against the hard palate, forward [CA92, FA90]"),
    "L": ((4.0, 0.0, 10.5, 1.5), "palatal lateral: the dorsum against the hard palate, the sides lowered "
                                "[CA92, FA90]"),
    "j": ((2.5, 2.0, 9.0, 3.0), "palatal approximant: a closer, more forward /i/ [CA92]"),
    "w": ((-2.0, -4.0, 6.0, -6.0), "labial-velar approximant: a closer /u/, the body raised and back [CA92]"),
}
# Dominance by degree of articulatory constraint [RE97]: per channel (alpha, k_R); theta per class.
_CONTACT = "the closure or contact is the sound's goal: strongly dominant, always reached [RE97, FA90]"
_HELD = "the constriction is critical for the sound: dominant and resistant [RE97]"
_LOOSE = "this part of the tongue is loosely constrained: it follows the context [RE97]"
_FREE = "the tongue is free for a labial: weak dominance, the vowels shape it [RE97]"
_VOWEL = "a vowel's tongue posture yields to the consonants (moderate resistance) [RE97]"
TONGUE_DOMINANCE: dict[str, tuple[dict[str, tuple[float, float, str]], float]] = {
    # class: ({channel: (alpha, k_r, why)}, theta)
    "dental": ({"TTH": (2.5, 1.0, _CONTACT), "TTA": (1.5, 0.7, _HELD), "TBH": (1.0, 0.5, _LOOSE),
                "TBA": (0.8, 0.4, _LOOSE)}, 40.0),
    "lateral": ({"TTH": (2.0, 0.9, _CONTACT), "TTA": (1.2, 0.6, _HELD), "TBH": (0.8, 0.3, _LOOSE),
                 "TBA": (0.8, 0.3, _LOOSE)}, 40.0),
    "trill": ({"TTH": (2.0, 0.9, _HELD), "TTA": (1.5, 0.7, _HELD), "TBH": (1.5, 0.7, _HELD),
               "TBA": (1.2, 0.6, _HELD)}, 40.0),
    "sibilant": ({"TTH": (2.0, 0.9, _HELD), "TTA": (1.5, 0.8, _HELD), "TBH": (1.5, 0.7, _HELD),
                  "TBA": (1.2, 0.6, _HELD)}, 40.0),
    "postalveolar": ({"TTH": (2.0, 0.9, _HELD), "TTA": (1.5, 0.8, _HELD), "TBH": (2.0, 0.8, _HELD),
                      "TBA": (1.2, 0.6, _HELD)}, 35.0),
    "palatal": ({"TTH": (1.5, 0.6, _LOOSE), "TTA": (1.5, 0.7, _HELD), "TBH": (2.5, 1.0, _CONTACT),
                 "TBA": (2.0, 0.9, _HELD)}, 30.0),
    "velar": ({"TTH": (0.8, 0.3, _LOOSE), "TTA": (0.8, 0.3, _LOOSE), "TBH": (2.5, 1.0, _CONTACT),
               "TBA": (1.0, 0.4, "the velar closure moves along the velum with the vowel: loose advancement "
                                 "[FA90, RE97]")}, 45.0),
    "glide": ({"TTH": (1.0, 0.4, _LOOSE), "TTA": (1.0, 0.4, _LOOSE), "TBH": (1.5, 0.6, _HELD),
               "TBA": (1.2, 0.5, _HELD)}, 35.0),
    "labial": ({ch: (0.6, 0.1, _FREE) for ch in TONGUE_CHANNELS}, 40.0),
    "vowel": ({ch: (1.0, 0.4, _VOWEL) for ch in TONGUE_CHANNELS}, 20.0),
}
TONGUE_CLASS: dict[str, str] = {
    **{p: "dental" for p in ("t", "d", "n")}, "l": "lateral", "r": "trill",
    **{p: "sibilant" for p in ("s", "z", "ts", "dz")}, **{p: "postalveolar" for p in ("S", "tS", "dZ")},
    **{p: "palatal" for p in ("J", "L")}, **{p: "velar" for p in ("k", "g")}, "j": "glide", "w": "glide",
    **{p: "labial" for p in ("p", "b", "m", "f", "v")}, **{v: "vowel" for v in ITALIAN_VOWELS},
}


def tongue(table: Table) -> None:
    """The tongue channels of every phoneme of the Italian flavour (TONGUE_TARGETS, TONGUE_DOMINANCE)."""
    pause(table, TONGUE_CHANNELS)
    for ph, (targets, why) in TONGUE_TARGETS.items():
        dominance, theta = TONGUE_DOMINANCE[TONGUE_CLASS[ph]]
        for ch, target in zip(TONGUE_CHANNELS, targets):
            alpha, k_r, dwhy = dominance[ch]
            s = Spec().set(why, target=target)
            if ph == REFERENCE:
                s.set("reference phoneme: alpha fixed to 1 on every channel (the scale of dominance)", alpha=1.0)
            else:
                s.set(dwhy, alpha=alpha)
            s.set(dwhy, k_r=k_r)
            if TONGUE_CLASS[ph] == "vowel":
                s.set("vowels are the long, dominant gestures of a VCV: long reach (1/theta = 50 ms)",
                      theta_bw=theta, theta_fw=theta)
            else:
                s.set(f"a consonant gesture: shorter reach than a vowel (1/theta ~ {1000 / theta:.0f} ms)",
                      theta_bw=theta, theta_fw=theta)
            if ph in ("t", "d", "k", "g"):
                s.set("stop release is quicker than its closing: shorter forward reach", theta_fw=theta * 1.25)
            table[ph][ch] = s
    # /i/ holds its high front body more firmly than the other vowels [RE97]
    table["i"]["TBH"].set("the high front dorsum of /i/ is the most constrained vowel posture [RE97]",
                          alpha=1.3, k_r=0.5)


def build(vowel_set: tuple[str, ...] = VOWELS) -> ParameterTable:
    """The default session's table (/i a u/), or with ``ITALIAN_VOWELS`` the Italian flavour's."""
    italian = vowel_set == ITALIAN_VOWELS
    out = OUT_ITALIAN if italian else OUT
    phonemes = [PAUSE, *vowel_set, *CONSONANTS, *(SEMIVOWELS if italian else ())]
    channels = CHANNELS + TONGUE_CHANNELS if italian else CHANNELS
    specs: Table = {p: {} for p in phonemes}
    pause(specs)
    vowels(specs, vowel_set)
    consonants(specs, semivowels=italian)
    if italian:
        italian_rounding(specs)
        tongue(specs)
    values = {p: {ch: specs[p][ch].complete().values for ch in channels} for p in phonemes}
    reasons = {p: {ch: specs[p][ch].reasons for ch in channels} for p in phonemes}
    table = ParameterTable(
        variant="modified",
        channels={
            ch: ChannelSettings(reference_phoneme=REFERENCE, unit="mm", beta=1.0, edge_extent=1.0, apex_fraction=0.5)
            for ch in channels
        },
        values=values,
        bounds={ch: {"target": TARGET_BOUNDS[ch]} for ch in channels},
        reasons=reasons,
        metadata={
            "method": "ground truth (hand-chosen, see reasons)",
            "corpus": ("coartic synthetic ELITE-style session, --flavour italian: every Italian phoneme "
                       "(corpus-synthetic/)" if italian else "coartic synthetic ELITE-style session (corpus-synthetic/)"),
            "note": "beta = 1, edge extent 1 s, apex fraction 0.5 on every channel; reference phoneme /a/",
        } | ({"literature": "vowel postures: Magno Caldognetto et al. 1995, 1998; Farnetani 1999; Canepari 1992; "
                            "Lindblom & Sundberg 1971; rounding: Fromkin 1964, Linker 1982; tongue: Canepari 1992, "
                            "Farnetani 1990, Recasens et al. 1997 (corpus-synthetic/README.md)"} if italian else {}),
        source=str(out),
    )
    table.validate()
    return table


def main() -> None:
    build().save(OUT)
    print(f"wrote {OUT}")
    build(ITALIAN_VOWELS).save(OUT_ITALIAN)
    print(f"wrote {OUT_ITALIAN}")


if __name__ == "__main__":
    main()
