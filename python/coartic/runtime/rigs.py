"""The rigs people already have, driven by the model: ARKit blendshape weights, Meta (Oculus) visemes
and Rhubarb Lip Sync mouth cues, each computed from one `Animation` (its channels, neutral face and
the dominance weights of its segments).

- **ARKit** (`arkit_weights`): Apple's 52 blendshape names, all present; the mouth and jaw ones
  are driven from the channel displacements d_C = C − C_neutral (mm), each by the part of the
  movement it stands for, eyeBlinkLeft/Right by the FAP file's blinks, the rest are 0. `ARKIT_BASIS` is what weight 1 of each driven shape
  means in channel millimetres, so that the weights are a decomposition of the channels (tested:
  jaw and lip opening rebuilt from the weights to 1e-9 mm where no weight saturates) and the
  ARKit morph set of the glTF (coartic.face.gltf, `--gltf-morphs arkit`) poses the face from them.
- **Meta visemes** (`viseme_weights`): the 15 visemes sil PP FF TH DD kk CH SS nn RR aa E ih oh
  ou; each frame's weights are the dominance shares of the segments (how much each segment's target
  counts in the model at that frame, averaged over the modelled channels) summed by viseme.
- **Rhubarb** Lip Sync's mouth cues: coartic.runtime.rhubarb.

The mapping and why each weight is what it is: docs/RUNTIME.md, "The rigs people have".
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from coartic.outputs import atomic_write_text
from coartic.runtime.animate import SHARE_FRAMES, Animation
from coartic.face.deform import ROLL_FULL_MM, ROLL_OPEN_MM
from coartic.runtime.errors import AnimationError
from coartic.runtime.fap import blink_profile
from coartic.table import CHANNELS, PAUSE

if TYPE_CHECKING:
    from coartic.runtime.exporters import ExportSettings, FaceAnimation, RigOptions

# Apple ARKit ARFaceAnchor.BlendShapeLocation, in Apple's documentation order.
ARKIT_NAMES: tuple[str, ...] = (
    "eyeBlinkLeft", "eyeLookDownLeft", "eyeLookInLeft", "eyeLookOutLeft", "eyeLookUpLeft", "eyeSquintLeft",
    "eyeWideLeft", "eyeBlinkRight", "eyeLookDownRight", "eyeLookInRight", "eyeLookOutRight", "eyeLookUpRight",
    "eyeSquintRight", "eyeWideRight", "jawForward", "jawLeft", "jawRight", "jawOpen", "mouthClose",
    "mouthFunnel", "mouthPucker", "mouthLeft", "mouthRight", "mouthSmileLeft", "mouthSmileRight",
    "mouthFrownLeft", "mouthFrownRight", "mouthDimpleLeft", "mouthDimpleRight", "mouthStretchLeft",
    "mouthStretchRight", "mouthRollLower", "mouthRollUpper", "mouthShrugLower", "mouthShrugUpper",
    "mouthPressLeft", "mouthPressRight", "mouthLowerDownLeft", "mouthLowerDownRight", "mouthUpperUpLeft",
    "mouthUpperUpRight", "browDownLeft", "browDownRight", "browInnerUp", "browOuterUpLeft", "browOuterUpRight",
    "cheekPuff", "cheekSquintLeft", "cheekSquintRight", "noseSneerLeft", "noseSneerRight", "tongueOut",
)
assert len(ARKIT_NAMES) == 52 and len(set(ARKIT_NAMES)) == 52

# Channel movement (mm) that weight 1 of a shape stands for. The ranges are the extent of each
# movement in speech and beyond it, so that ordinary speech stays well inside 0..1 and a rig's
# extreme pose is an extreme of the mouth (docs/RUNTIME.md gives the reasons):
JAW_OPEN_MM = 20.0  # nose-chin distance gained at jawOpen 1 (an /a/ of the synthetic speaker: +10 mm)
LIP_PER_JAW = 1.0  # the lower lip drops with the chin when only the jaw opens
LOWER_DOWN_MM = 10.0  # lower lip pulled down from the jaw (per side; the midline moves the mean of both)
UPPER_UP_MM = 8.0  # upper lip raised
UPPER_DOWN_MM = 4.0  # upper lip drawn down over the upper teeth with the lips apart (mouthRollUpper)
PRESS_MM = 5.0  # lips pressed together past contact (the overlap of both lips)
SHRUG_MM = 5.0  # the lower lip pushed up from where the jaw and mouthClose put it (/f v/: under the teeth)
STRETCH_MM = 8.0  # one corner pulled outwards (LR changes by twice this with both sides)
NARROW_MM = 15.0  # mouth width lost to rounding
PROTRUDE_MM = 4.0  # lips pushed forwards: a rounded vowel narrows the mouth ~4 mm per mm of protrusion
FUNNEL_OPEN_MM = 6.0  # lip opening (both lips) that a funnel of weight 1 carries
# The lower lip's roll is the face rig's (coartic.face.deform.roll_angle): drawn back ROLL_FULL_MM
# and not lowered, it rolls in fully under the upper incisors (/f v/); lowered ROLL_OPEN_MM or more
# (any open vowel), it does not roll at all, however far back it is (/i a/ retract the lips).
# ARKit shape -> channel displacement (mm) at weight 1; the L/R shapes each carry half of the
# midline's movement (the rig's side FAPs move fully, coartic.face.gltf)
ARKIT_BASIS: dict[str, dict[str, float]] = {
    "jawOpen": {"JO": JAW_OPEN_MM, "LLO": JAW_OPEN_MM * LIP_PER_JAW},
    "mouthClose": {"LLO": -JAW_OPEN_MM * LIP_PER_JAW},
    "mouthLowerDownLeft": {"LLO": LOWER_DOWN_MM / 2}, "mouthLowerDownRight": {"LLO": LOWER_DOWN_MM / 2},
    "mouthUpperUpLeft": {"ULO": UPPER_UP_MM / 2}, "mouthUpperUpRight": {"ULO": UPPER_UP_MM / 2},
    "mouthPressLeft": {"ULO": -PRESS_MM / 4, "LLO": -PRESS_MM / 4},
    "mouthPressRight": {"ULO": -PRESS_MM / 4, "LLO": -PRESS_MM / 4},
    "mouthShrugLower": {"LLO": -SHRUG_MM},
    "mouthStretchLeft": {"LR": STRETCH_MM}, "mouthStretchRight": {"LR": STRETCH_MM},
    "mouthPucker": {"LR": -NARROW_MM, "ULP": PROTRUDE_MM, "LLP": PROTRUDE_MM},
    "mouthFunnel": {"LR": -NARROW_MM, "ULP": PROTRUDE_MM, "LLP": PROTRUDE_MM, "ULO": FUNNEL_OPEN_MM / 2,
                    "LLO": FUNNEL_OPEN_MM / 2},
    "mouthRollLower": {"LLP": -ROLL_FULL_MM},
    "mouthRollUpper": {"ULO": -UPPER_DOWN_MM},
}
# the blinks of the FAP file (coartic.runtime.fap.blink_profile: the same schedule), eyelid FAPs 19, 20
ARKIT_BLINKS: dict[str, int] = {"eyeBlinkLeft": 19, "eyeBlinkRight": 20}
ARKIT_DRIVEN: tuple[str, ...] = tuple(n for n in ARKIT_NAMES if n in ARKIT_BASIS or n in ARKIT_BLINKS)

# Meta (Oculus) Lipsync's 15 visemes, in its order.
VISEMES: tuple[str, ...] = ("sil", "PP", "FF", "TH", "DD", "kk", "CH", "SS", "nn", "RR", "aa", "E", "ih", "oh", "ou")
# Model phonemes (docs/ARCHITECTURE.md, SAMPA-like) -> viseme, by place and manner as Meta defines
# them: PP bilabials, FF labiodentals, TH dentals, DD alveolar stops, kk velars, CH postalveolars,
# SS sibilants (and the affricates /ts dz/, which end in one), nn nasals and laterals, RR /r/.
PHONEME_VISEME: dict[str, str] = {
    PAUSE: "sil", "p": "PP", "b": "PP", "m": "PP", "f": "FF", "v": "FF", "T": "TH", "D": "TH",
    "t": "DD", "d": "DD", "k": "kk", "g": "kk", "N": "kk", "tS": "CH", "dZ": "CH", "S": "CH", "Z": "CH",
    "s": "SS", "z": "SS", "ts": "SS", "dz": "SS", "n": "nn", "l": "nn", "J": "nn", "L": "nn", "r": "RR",
    "R": "RR", "a": "aa", "A": "aa", "e": "E", "E": "E", "i": "ih", "I": "ih", "j": "ih", "o": "oh", "O": "oh",
    "u": "ou", "U": "ou", "w": "ou", "y": "ou", "h": "sil",
}

def _deltas(animation: Animation) -> dict[str, NDArray[np.float64]]:
    missing = [c for c in CHANNELS if c not in animation.neutral]
    if missing:
        raise AnimationError(f"no neutral posture for channel(s) {', '.join(missing)}: the table needs a pause "
                             f"phoneme {PAUSE!r}, whose targets are the face at rest that rig weights start from")
    return {c: np.asarray(animation.channels[c], dtype=float) - animation.neutral[c] for c in CHANNELS}


def lower_lip_roll(d_llp: NDArray[np.float64], d_llo: NDArray[np.float64]) -> NDArray[np.float64]:
    """How far (0..1) the lower lip rolls in, as the face rig rolls it (coartic.face.deform.roll_angle
    is this times ROLL_MAX): drawn back (d_LLP < 0) and not lowered (d_LLO, positive down)."""
    out: NDArray[np.float64] = (np.clip(-d_llp / ROLL_FULL_MM, 0.0, 1.0)
                                * np.clip(1.0 - np.maximum(d_llo, 0.0) / ROLL_OPEN_MM, 0.0, 1.0))
    return out


def arkit_weights(animation: Animation) -> NDArray[np.float64]:
    """(frames, 52) ARKit blendshape weights in 0..1, columns in ARKIT_NAMES order.

    Each lip's movement is taken apart in a fixed order, every step removing what its shape
    carries, so that the weights rebuild the jaw, each lip's opening and the width wherever no
    weight saturates (docs/RUNTIME.md, "The rigs people have")."""
    d = _deltas(animation)
    n = animation.n_frames
    w = {name: np.zeros(n) for name in ARKIT_NAMES}
    jaw = np.clip(d["JO"] / JAW_OPEN_MM, 0.0, 1.0)
    w["jawOpen"] = jaw
    upper = d["ULO"].copy()  # the upper lip's own movement, positive up
    lower = d["LLO"] - jaw * JAW_OPEN_MM * LIP_PER_JAW  # the lower lip's, positive down, from the jaw's carry
    # lips past contact (they overlap: /p b m/) are pressed, both alike
    press = np.clip(np.maximum(-(d["ULO"] + d["LLO"]), 0.0) / PRESS_MM, 0.0, 1.0)
    upper, lower = upper + press * PRESS_MM / 2, lower + press * PRESS_MM / 2
    # a lower lip held above where the jaw carries it: first closed against the open jaw
    # (mouthClose, at most as much as the jaw opened), the rest pushed up (mouthShrugLower: /f v/)
    close = np.minimum(np.maximum(-lower, 0.0) / (JAW_OPEN_MM * LIP_PER_JAW), jaw)
    lower = lower + close * JAW_OPEN_MM * LIP_PER_JAW
    shrug = np.clip(np.maximum(-lower, 0.0) / SHRUG_MM, 0.0, 1.0)
    lower = lower + shrug * SHRUG_MM
    w["mouthClose"], w["mouthShrugLower"] = close, shrug
    # rounding: the narrowing and the protrusion together, the weight whose (NARROW_MM, PROTRUDE_MM)
    # movement is nearest (least squares, mm) to the lips' (a /u/ narrows 12 mm and protrudes 3:
    # both within 0.2 mm); a funnel is a rounding whose lips are apart, as far as both are open
    protrusion = np.maximum((d["ULP"] + d["LLP"]) / 2.0, 0.0)
    narrowing = np.maximum(-d["LR"], 0.0)
    rounding = np.clip((narrowing * NARROW_MM + protrusion * PROTRUDE_MM) / (NARROW_MM**2 + PROTRUDE_MM**2),
                       0.0, 1.0)
    # a lower lip rolled in under the upper incisors (/f v/) is not pushed forwards too: the
    # rounding's protrusion of both lips pushed it out of its roll (at an /f/ after /u/, whose
    # corners are still narrowed, the incisors hid and the lips closed to a slit), so the rounding
    # gives way as far as the lip rolls: the incisors show as on the FAP face, the corners are wider
    roll = lower_lip_roll(d["LLP"], d["LLO"])
    rounding = rounding * (1.0 - roll)
    funnel = np.minimum(rounding, np.maximum(np.minimum(upper, lower), 0.0) / (FUNNEL_OPEN_MM / 2))
    w["mouthFunnel"], w["mouthPucker"] = funnel, rounding - funnel
    upper, lower = upper - funnel * FUNNEL_OPEN_MM / 2, lower - funnel * FUNNEL_OPEN_MM / 2
    # an upper lip below rest that no press explains (the lips are apart) is drawn over the teeth
    w["mouthRollUpper"] = np.clip(np.maximum(-upper, 0.0) / UPPER_DOWN_MM, 0.0, 1.0)
    for side in ("Left", "Right"):
        w[f"mouthUpperUp{side}"] = np.clip(upper / UPPER_UP_MM, 0.0, 1.0)
        w[f"mouthLowerDown{side}"] = np.clip(lower / LOWER_DOWN_MM, 0.0, 1.0)
        w[f"mouthPress{side}"] = press
        w[f"mouthStretch{side}"] = np.clip(d["LR"] / (2.0 * STRETCH_MM), 0.0, 1.0)
    for name in ARKIT_BLINKS:
        w[name] = blink_profile(animation.times)
    w["mouthRollLower"] = roll
    from coartic.runtime.expression import expression_arkit  # an emotion's brows, eyes, cheeks, smile

    for name, add in expression_arkit(animation).items():
        w[name] = np.clip(w[name] + add, 0.0, 1.0)
    return np.column_stack([w[name] for name in ARKIT_NAMES])


def arkit_channels(weights: NDArray[np.float64]) -> dict[str, NDArray[np.float64]]:
    """Channel displacements (mm) that ARKit weights stand for: Σ_k w_k ARKIT_BASIS[k]."""
    out = {c: np.zeros(weights.shape[0]) for c in CHANNELS}
    for k, name in enumerate(ARKIT_NAMES):
        for c, mm in ARKIT_BASIS.get(name, {}).items():
            out[c] += weights[:, k] * mm
    return out


def _viseme_of(phoneme: str) -> str:
    v = PHONEME_VISEME.get(phoneme) or PHONEME_VISEME.get(phoneme.rstrip(":"))  # long vowels as short
    if v is None:
        raise AnimationError(f"phoneme {phoneme!r} has no Meta viseme (coartic.runtime.rigs.PHONEME_VISEME "
                             f"maps {' '.join(sorted(PHONEME_VISEME))})")
    return v


def segment_shares(animation: Animation, start: int = 0, stop: int | None = None) -> NDArray[np.float64]:
    """(frames, segments) for frames start..stop: each segment's dominance share, averaged over
    the modelled channels."""
    chans = animation.modelled
    total = sum(animation.segment_shares(c, start, stop) for c in chans)
    out: NDArray[np.float64] = np.asarray(total) / len(chans)
    return out


def share_blocks(animation: Animation) -> list[tuple[int, int]]:
    n = animation.n_frames
    return [(a, min(a + SHARE_FRAMES, n)) for a in range(0, n, SHARE_FRAMES)]


def viseme_weights(animation: Animation) -> NDArray[np.float64]:
    """(frames, 15) Meta viseme weights (VISEMES order), each row summing to 1."""
    column = np.array([VISEMES.index(_viseme_of(p)) for p in animation.segments.labels], dtype=np.int64)
    onehot = np.zeros((column.size, len(VISEMES)))
    onehot[np.arange(column.size), column] = 1.0
    out = np.empty((animation.n_frames, len(VISEMES)))
    for a, b in share_blocks(animation):
        out[a:b] = segment_shares(animation, a, b) @ onehot
    return out


def dominant_segments(animation: Animation) -> NDArray[np.int64]:
    """The index of the segment with the largest dominance share at every frame."""
    out = np.empty(animation.n_frames, dtype=np.int64)
    for a, b in share_blocks(animation):
        out[a:b] = np.argmax(segment_shares(animation, a, b), axis=1)
    return out


def _num(x: float) -> str:
    return repr(float(x))


def write_curves_csv(path: Path, animation: Animation, names: tuple[str, ...], weights: NDArray[np.float64]) -> Path:
    """`frame,time,<name>...`, one row per frame, floats with repr (read back bit for bit)."""
    rows = [",".join(("frame", "time", *names))]
    for k in range(animation.n_frames):
        rows.append(",".join((str(k), _num(animation.times[k]), *(_num(v) for v in weights[k]))))
    atomic_write_text(path, "\n".join(rows) + "\n")
    return path


def write_arkit_json(path: Path, animation: Animation, weights: NDArray[np.float64], audio: str | None) -> Path:
    """The layout of NVIDIA Audio2Face's blendshape export (exportFps, numPoses, numFrames,
    facsNames, weightMat), which Omniverse, Unreal and Blender importers read."""
    doc = {"exportFps": animation.fps, "trackPath": audio or "", "numPoses": len(ARKIT_NAMES),
           "numFrames": animation.n_frames, "facsNames": list(ARKIT_NAMES),
           "weightMat": [[float(v) for v in row] for row in weights]}
    atomic_write_text(path, json.dumps(doc) + "\n")
    return path


# Viseme name sets (`--viseme-names`): the 15 weights under the names a rig's shape keys carry.
# Ready Player Me's avatars and VRChat's Oculus-style rigs name them viseme_sil ... viseme_U.
RPM_VISEMES: tuple[str, ...] = ("viseme_sil", "viseme_PP", "viseme_FF", "viseme_TH", "viseme_DD", "viseme_kk",
                                "viseme_CH", "viseme_SS", "viseme_nn", "viseme_RR", "viseme_aa", "viseme_E",
                                "viseme_I", "viseme_O", "viseme_U")
# VRM (1.0 expression presets; 0.x's A I U E O) has five mouth shapes, the vowels. Each Meta viseme
# goes to the vowel whose mouth it is nearest: the vowels to their own; the tongue consonants (teeth
# near together, lips a little spread) to ih; CH (rounded in Italian and English) to ou; PP, FF and
# sil to none (the closed mouth is VRM's neutral face). Weights of one vowel add up.
VRM_VISEMES: tuple[str, ...] = ("aa", "ih", "ou", "ee", "oh")
VRM_OF: dict[str, str | None] = {"sil": None, "PP": None, "FF": None, "TH": "ih", "DD": "ih", "kk": "ih",
                                 "CH": "ou", "SS": "ih", "nn": "ih", "RR": "ih", "aa": "aa", "E": "ee",
                                 "ih": "ih", "oh": "oh", "ou": "ou"}
VISEME_NAME_SETS: tuple[str, ...] = ("meta", "rpm", "vrm")


def named_visemes(weights: NDArray[np.float64], names: str) -> tuple[tuple[str, ...], NDArray[np.float64]]:
    """Meta's 15 viseme weights (VISEMES order) under the name set `names`: meta (Oculus), rpm
    (Ready Player Me, VRChat: viseme_sil ... viseme_U) or vrm (five vowels, VRM_OF)."""
    if names == "meta":
        return VISEMES, weights
    if names == "rpm":
        return RPM_VISEMES, weights
    if names == "vrm":
        out = np.zeros((weights.shape[0], len(VRM_VISEMES)))
        for k, v in enumerate(VISEMES):
            target = VRM_OF[v]
            if target is not None:
                out[:, VRM_VISEMES.index(target)] += weights[:, k]
        return VRM_VISEMES, out
    raise AnimationError(f"--viseme-names {names!r}: choose {', '.join(VISEME_NAME_SETS)} (Meta/Oculus, "
                         "Ready Player Me/VRChat, VRM)")


def _hann_smooth(y: NDArray[np.float64], frames: int) -> NDArray[np.float64]:
    """A zero-phase moving average weighted by a Hann window `frames` wide (odd), the ends held."""
    if frames < 3:
        return y
    window = np.hanning(frames + 2)[1:-1]
    window /= window.sum()
    half = frames // 2
    padded = np.concatenate([np.repeat(y[:1], half, axis=0), y, np.repeat(y[-1:], half, axis=0)])
    out: NDArray[np.float64] = np.stack([np.convolve(padded[:, j], window, mode="valid") for j in range(y.shape[1])], axis=1)
    return out


def _hold(y: NDArray[np.float64], frames: int) -> NDArray[np.float64]:
    """A centred running maximum `frames` wide (odd): every peak held for at least that long."""
    if frames < 2:
        return y
    half = frames // 2
    padded = np.concatenate([np.repeat(y[:1], half, axis=0), y, np.repeat(y[-1:], half, axis=0)])
    windows = np.lib.stride_tricks.sliding_window_view(padded, frames, axis=0)
    out: NDArray[np.float64] = windows.max(axis=-1)
    return out


def _odd_frames(seconds: float, fps: float) -> int:
    n = int(round(seconds * fps))
    return n + 1 if n % 2 == 0 and n > 0 else n


def shape_curves(weights: NDArray[np.float64], names: tuple[str, ...], fps: float, options: RigOptions,
                 fixed: tuple[str, ...] = (), rest: str | None = None) -> NDArray[np.float64]:
    """The curves as the rig options ask (docs/RUNTIME.md, "Gain, scale, smoothing and hold"), in order:
    smoothed over `options.smooth` s (Hann, zero phase), peaks held `options.hold` s, scaled by the
    gain and by each shape's own scale, clipped to 0..1. The shapes `fixed` (the blinks) are left as
    they are; `rest` (a viseme set's silence) is what the others leave of 1 (the rows sum to 1)."""
    scale = dict(options.shape_scale)  # names of another set written beside (check_shape_scale) left out
    y = np.array(weights, dtype=np.float64)
    if options.gain == 1.0 and not scale and _odd_frames(options.smooth, fps) < 3 and _odd_frames(options.hold, fps) < 2:
        return y  # the model's curves as they are
    moving = [k for k, n in enumerate(names) if n not in fixed and n != rest]
    part = y[:, moving]
    part = _hann_smooth(part, _odd_frames(options.smooth, fps))
    part = _hold(part, _odd_frames(options.hold, fps))
    part = part * options.gain * np.array([scale.get(names[k], 1.0) for k in moving])
    part = np.clip(part, 0.0, 1.0)
    if rest is not None:  # the shares stay shares: the silence is what is left, and past 1 they shrink
        total = part.sum(axis=1, keepdims=True)
        part = part / np.maximum(total, 1.0)
        y[:, names.index(rest)] = np.maximum(1.0 - part.sum(axis=1), 0.0)
    y[:, moving] = part
    return y


def check_shape_scale(options: RigOptions, exports: tuple[str, ...]) -> None:
    """Every --rig-scale name is a shape of a curve set being written (--export arkit, visemes)."""
    sets = {"arkit": ARKIT_NAMES, "visemes": named_visemes(np.zeros((1, len(VISEMES))), options.viseme_names)[0]}
    known = [n for e in exports if e in sets for n in sets[e]]
    unknown = [n for n, _ in options.shape_scale if n not in known]
    if unknown:
        raise AnimationError(f"--rig-scale {', '.join(unknown)}: no such shape in the curves written "
                             f"(--export {','.join(exports) or 'none'}); they are {' '.join(known) or 'none'}")


def write_visemes_json(path: Path, animation: Animation, weights: NDArray[np.float64], audio: str | None,
                       names: tuple[str, ...] = VISEMES) -> Path:
    """`{"fps", "frames", "visemes": [names], "weights": [[one per name, per frame]], "audio"}`."""
    doc = {"fps": animation.fps, "frames": animation.n_frames, "audio": audio, "visemes": list(names),
           "weights": [[float(v) for v in row] for row in weights]}
    atomic_write_text(path, json.dumps(doc) + "\n")
    return path


def export_arkit(fed: FaceAnimation, settings: ExportSettings) -> dict[str, Path]:
    """Exporter (coartic.runtime.exporters): NAME.arkit.csv and NAME.arkit.json, shaped by the rig options."""
    animation = fed.animation
    w = shape_curves(fed.once(arkit_weights), ARKIT_NAMES, animation.fps, settings.rig, fixed=tuple(ARKIT_BLINKS))
    return {"arkit_csv": write_curves_csv(settings.out / f"{settings.name}.arkit.csv", animation, ARKIT_NAMES, w),
            "arkit_json": write_arkit_json(settings.out / f"{settings.name}.arkit.json", animation, w,
                                           settings.audio_name())}


def export_visemes(fed: FaceAnimation, settings: ExportSettings) -> dict[str, Path]:
    """Exporter: NAME.visemes.csv and NAME.visemes.json, in the name set `settings.rig.viseme_names`."""
    animation = fed.animation
    names, w = named_visemes(fed.once(viseme_weights), settings.rig.viseme_names)
    w = shape_curves(w, names, animation.fps, settings.rig, rest=names[0] if names[0].endswith("sil") else None)
    return {"visemes_csv": write_curves_csv(settings.out / f"{settings.name}.visemes.csv", animation, names, w),
            "visemes_json": write_visemes_json(settings.out / f"{settings.name}.visemes.json", animation, w,
                                               settings.audio_name(), names)}
