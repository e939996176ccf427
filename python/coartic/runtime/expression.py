"""The expression outside the mouth: what an emotion does to the brows, eyelids, cheeks and lip
corners, as MPEG-4 low-level FAPs and ARKit blendshapes (docs/EMOTIONS.md).

The lips' share of an emotion is fitted (the table's emotion targets, ``coartic.emotions``); what the
lip markers do not measure is placed here from the Facial Action Coding System's prototypes of
Ekman's six emotions (Ekman and Friesen 1978; the EMFACS prototypes): joy AU6+12 (cheeks raised, lip
corners pulled up, lower lids up), surprise AU1+2+5 (brows raised, upper lids up), sadness AU1+4+15
(inner brows raised and drawn together, lip corners down), disgust AU9+10 (nose wrinkled, lower lids
and cheeks up, brows lowered), anger AU4+5+7 (brows lowered and drawn together, upper lids up, lower
lids tightened), fear AU1+2+4+5+20 (brows raised and drawn together, upper lids up). The values are
ours, of the size an MPEG-4 player's expression tables use; they scale with the intensity (0-1.5) and
follow an emotion markup's ramps (``coartic.emotions.expression_weights``).

FAP units (ISO/IEC 14496-2): the brows' raise and the cheeks ENS (eye-nose separation / 1024), the
brows' squeeze ES (eye separation / 1024), eyelids IRISD (iris diameter / 1024; positive closes), lip
corners MNS (positive up). The face coartic ships (``coartic.face``) moves them all: its brows,
cheeks and lower lids have zones of their own (``coartic.face.deform.upper_face_fields``), and its
ARKit morph set poses the expression's shapes through the same FAPs (``ARKIT_EXPRESSION``).
A corner's lift and stretch go to the outer contour's twin too (59/60, 53/54), as the lips' FAPs do
(``coartic.runtime.fap.OUTER_TWIN``): the corner is one vertex of both contours.

The same emotion goes into the FAP file as MPEG-4's high-level expression too (FAP 2,
``runtime.fap.expression_fap2``): per frame the two strongest emotions as expression_select1/2 (MPEG-4's codes,
``runtime.fap.EXPRESSION_SELECT``) with their intensities on MPEG-4's 0-63 (63 the expression as
recorded: an intensity above 1 is sent as 63, its excess carried by the low-level FAPs only),
init_face and expression_def 0 (the player's own expression tables); a frame without an emotion
sends expression 0 (none), so that a player does not keep the last one.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np
from numpy.typing import NDArray

from coartic.emotions import expression_weights
from coartic.runtime.animate import Animation

F64 = NDArray[np.float64]

# emotion -> low-level FAP -> value at intensity 1 (on a face of ENS 31 mm, ES 64 mm, IRISD 9.6 mm,
# MNS 31 mm, coartic's: a brow raised 280 ENS goes up 8.4 mm, squeezed 80 ES goes in 5 mm). 19/20 close_t_l/r_eyelid, 21/22 close_b_l/r_eyelid,
# 31-36 raise_l/r_i/m/o_eyebrow, 37/38 squeeze_l/r_eyebrow, 41/42 lift_l/r_cheek, 12/13 raise_l/r_cornerlip.
EXPRESSION_FAPS: dict[str, dict[int, float]] = {
    "joy": {41: 180.0, 42: 180.0, 21: 120.0, 22: 120.0, 12: 90.0, 13: 90.0},
    "surprise": {31: 260.0, 32: 260.0, 33: 280.0, 34: 280.0, 35: 240.0, 36: 240.0, 19: -180.0, 20: -180.0},
    "sadness": {31: 220.0, 32: 220.0, 33: 60.0, 34: 60.0, 35: -60.0, 36: -60.0, 37: 40.0, 38: 40.0,
                19: 150.0, 20: 150.0, 12: -80.0, 13: -80.0},
    "disgust": {31: -80.0, 32: -80.0, 33: -100.0, 34: -100.0, 35: -60.0, 36: -60.0, 21: 120.0, 22: 120.0,
                41: 100.0, 42: 100.0, 12: -40.0, 13: -40.0},
    "anger": {31: -180.0, 32: -180.0, 33: -160.0, 34: -160.0, 35: -100.0, 36: -100.0, 37: 80.0, 38: 80.0,
              19: -80.0, 20: -80.0, 21: 140.0, 22: 140.0},
    "fear": {31: 260.0, 32: 260.0, 33: 160.0, 34: 160.0, 35: 60.0, 36: 60.0, 37: 50.0, 38: 50.0,
             19: -220.0, 20: -220.0},
}
# The same prototypes as ARKit blendshape weights at intensity 1 (0-1 each).
EXPRESSION_ARKIT: dict[str, dict[str, float]] = {
    "joy": {"cheekSquintLeft": 0.6, "cheekSquintRight": 0.6, "eyeSquintLeft": 0.4, "eyeSquintRight": 0.4,
            "mouthSmileLeft": 0.6, "mouthSmileRight": 0.6},
    "surprise": {"browInnerUp": 0.8, "browOuterUpLeft": 0.8, "browOuterUpRight": 0.8, "eyeWideLeft": 0.6,
                 "eyeWideRight": 0.6},
    "sadness": {"browInnerUp": 0.7, "browDownLeft": 0.2, "browDownRight": 0.2, "mouthFrownLeft": 0.5,
                "mouthFrownRight": 0.5, "eyeBlinkLeft": 0.15, "eyeBlinkRight": 0.15},
    "disgust": {"noseSneerLeft": 0.7, "noseSneerRight": 0.6, "browDownLeft": 0.4, "browDownRight": 0.4,
                "eyeSquintLeft": 0.4, "eyeSquintRight": 0.4, "cheekSquintLeft": 0.3, "cheekSquintRight": 0.3},
    "anger": {"browDownLeft": 0.8, "browDownRight": 0.8, "eyeWideLeft": 0.3, "eyeWideRight": 0.3,
              "eyeSquintLeft": 0.4, "eyeSquintRight": 0.4},
    "fear": {"browInnerUp": 0.8, "browOuterUpLeft": 0.3, "browOuterUpRight": 0.3, "browDownLeft": 0.2,
             "browDownRight": 0.2, "eyeWideLeft": 0.8, "eyeWideRight": 0.8},
}


# The expression's ARKit shapes at weight 1 as low-level FAPs: how coartic's face poses them in its
# ARKit morph set (coartic.face.gltf.arkit_morphs), chosen so that EXPRESSION_ARKIT's weights give
# about EXPRESSION_FAPS' values (surprise's browInnerUp 0.8 + browOuterUp 0.8 raise the brows 256
# ENS at the inner end and the top, 240 at the outer end; anger's browDown 0.8 lowers them 176, 160,
# 96 and squeezes 80 ES; eyeWide 0.6 lifts the upper lids 180 IRISD; joy's cheekSquint 0.6 lifts the
# cheeks 180 ENS, eyeSquint 0.4 the lower lids 120 IRISD, mouthSmile 0.6 the corners 90 MNS). A Left
# shape moves the face's left; a corner's FAP goes with its outer twin (12 with 59, 13 with 60).
ARKIT_EXPRESSION: dict[str, dict[int, float]] = {
    "browInnerUp": {31: 320.0, 32: 320.0, 33: 160.0, 34: 160.0},
    "browOuterUpLeft": {33: 160.0, 35: 300.0}, "browOuterUpRight": {34: 160.0, 36: 300.0},
    "browDownLeft": {31: -220.0, 33: -200.0, 35: -120.0, 37: 100.0},
    "browDownRight": {32: -220.0, 34: -200.0, 36: -120.0, 38: 100.0},
    "eyeWideLeft": {19: -300.0}, "eyeWideRight": {20: -300.0},
    "eyeSquintLeft": {21: 300.0}, "eyeSquintRight": {22: 300.0},
    "cheekSquintLeft": {41: 300.0}, "cheekSquintRight": {42: 300.0},
    "mouthSmileLeft": {12: 150.0, 59: 150.0}, "mouthSmileRight": {13: 150.0, 60: 150.0},
    "mouthFrownLeft": {12: -160.0, 59: -160.0}, "mouthFrownRight": {13: -160.0, 60: -160.0},
}


def _intensities(animation: Animation) -> dict[str, F64]:
    return expression_weights(animation.table, animation.times)


def table_asymmetry(animation: Animation, emotion: str) -> tuple[float, float]:
    """(ASYMX, ASYMY) mm of ``emotion`` in the animation's table: a fit's (``metadata.emotions.asymmetry``,
    measured on the corner markers) or a truth's; (0, 0) where the table has none."""
    meta = ((animation.table.metadata or {}).get("emotions") or {}) if animation.table is not None else {}
    per = (meta.get("asymmetry") or {}).get(emotion) or {}

    def value(v: Any) -> float:
        return float(v["value"]) if isinstance(v, dict) else float(v)

    return value(per.get("ASYMX", 0.0)), value(per.get("ASYMY", 0.0))


def expression_fap_offsets(animation: Animation, mns_mm: float, mw_mm: float) -> dict[int, F64]:
    """FAP -> what the animation's expression adds to it per frame (FAP units): ``EXPRESSION_FAPS``
    times each frame's intensity, and the table's corner asymmetries on the corners' FAPs (ASYMY half
    up on the right corner, 13, and half down on the left, 12, in MNS; ASYMX half out on the right, 7,
    and half in on the left, 6, in MW; ``mns_mm``, ``mw_mm`` the face's); inner contour's FAPs only.
    {} without an emotion; ``runtime.fap.animation_faps`` adds them, each corner's also on its outer
    twin (59, 60, 53, 54)."""
    added: dict[int, F64] = {}
    n = animation.n_frames
    for emotion, w in _intensities(animation).items():
        for fap, v in EXPRESSION_FAPS.get(emotion, {}).items():
            added[fap] = added.get(fap, np.zeros(n)) + v * w
        ax, ay = table_asymmetry(animation, emotion)
        for fap, mm, unit in ((12, -ay / 2, mns_mm / 1024.0), (13, ay / 2, mns_mm / 1024.0),
                              (6, -ax / 2, mw_mm / 1024.0), (7, ax / 2, mw_mm / 1024.0)):
            if mm:
                added[fap] = added.get(fap, np.zeros(n)) + (mm / unit) * w
    return added


def expression_arkit(animation: Animation) -> Mapping[str, F64]:
    """ARKit weights the animation's expression adds, per blendshape name (frames,); {} without one."""
    out: dict[str, F64] = {}
    for emotion, w in _intensities(animation).items():
        for name, v in EXPRESSION_ARKIT.get(emotion, {}).items():
            out[name] = out.get(name, np.zeros(animation.n_frames)) + v * w
    return out

