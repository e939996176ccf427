"""The rigs' curves as a user shapes them: viseme name sets (Meta/Oculus, Ready Player Me/VRChat, VRM),
gain, per-shape scale, smoothing and minimum hold, each with the effect docs/RUNTIME.md gives."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from coartic.cli import app
from coartic.runtime.errors import AnimationError
from coartic.runtime.exporters import RigOptions, parse_shape_scale
from coartic.runtime.pipeline import RuntimeOutput, animate_file
from coartic.runtime.rhubarb import TWEENS, mouth_cues
from coartic.runtime.rigs import (
    ARKIT_BLINKS,
    ARKIT_NAMES,
    RPM_VISEMES,
    VISEMES,
    VRM_VISEMES,
    arkit_weights,
    check_shape_scale,
    named_visemes,
    shape_curves,
    viseme_weights,
)
from coartic.table import ParameterTable
from face_helpers import APAFULA, GROUND_TRUTH


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> RuntimeOutput:
    tmp = tmp_path_factory.mktemp("curves")
    (tmp / "apafula.tsv").write_text(APAFULA)
    return animate_file(tmp / "apafula.tsv", ParameterTable.load(GROUND_TRUTH), tmp / "o", preview="none",
                        exports="arkit,visemes", rig=RigOptions(viseme_names="rpm"))


def test_viseme_name_sets(run: RuntimeOutput) -> None:
    w = viseme_weights(run.animation)
    doc = json.loads(run.files["visemes_json"].read_text())
    assert doc["visemes"] == list(RPM_VISEMES) and doc["visemes"][12:] == ["viseme_I", "viseme_O", "viseme_U"]
    np.testing.assert_allclose(np.array(doc["weights"]), w)  # the same 15 weights, Ready Player Me's names
    assert named_visemes(w, "meta") == (VISEMES, w)
    names, vrm = named_visemes(w, "vrm")
    assert names == VRM_VISEMES == ("aa", "ih", "ou", "ee", "oh")
    closed = w[:, [VISEMES.index(v) for v in ("sil", "PP", "FF")]].sum(axis=1)
    np.testing.assert_allclose(vrm.sum(axis=1) + closed, 1.0, atol=1e-12)  # every other viseme goes to a vowel
    frame = {ph: int(round(t * run.animation.fps)) for ph, t in (("a", 1.15), ("u", 0.90), ("p", 0.50))}
    assert names[int(np.argmax(vrm[frame["a"]]))] == "aa" and names[int(np.argmax(vrm[frame["u"]]))] == "ou"
    assert vrm[frame["p"]].sum() < 0.5  # the closure is VRM's neutral mouth
    with pytest.raises(AnimationError, match="--viseme-names 'arkit': choose meta, rpm, vrm"):
        RigOptions(viseme_names="arkit")


def test_gain_scale_smoothing_and_hold_as_documented(run: RuntimeOutput) -> None:
    """The figures of docs/RUNTIME.md ("Gain, scale, smoothing and hold"), on "# a p a f u l a #" at 25 fps."""
    anim = run.animation
    w = arkit_weights(anim)
    jaw, press, blink = (ARKIT_NAMES.index(n) for n in ("jawOpen", "mouthPressLeft", "eyeBlinkLeft"))

    def shaped(**kw: object) -> np.ndarray:
        return shape_curves(w, ARKIT_NAMES, anim.fps, RigOptions(**kw), fixed=tuple(ARKIT_BLINKS))  # type: ignore[arg-type]

    np.testing.assert_array_equal(shaped(), w)  # the defaults change nothing
    g = shaped(gain=1.5)
    assert w[:, jaw].max() == pytest.approx(0.497, abs=1e-3) and g[:, jaw].max() == pytest.approx(1.5 * w[:, jaw].max())
    assert g[:, press].max() == 1.0  # clipped to the rig's range
    np.testing.assert_array_equal(g[:, blink], w[:, blink])  # the blinks are not speech
    s = shaped(shape_scale=(("jawOpen", 0.5),))
    np.testing.assert_allclose(s[:, jaw], 0.5 * w[:, jaw])
    np.testing.assert_array_equal(np.delete(s, jaw, axis=1), np.delete(w, jaw, axis=1))
    # smoothing lowers the short /p/ press more than the long /a/ jaw, and delays neither peak
    for width, press_peak, jaw_peak in ((0.08, 0.822, 0.484), (0.16, 0.683, 0.451)):
        sm = shaped(smooth=width)
        assert sm[:, press].max() == pytest.approx(press_peak, abs=2e-3) and sm[:, jaw].max() == pytest.approx(jaw_peak, abs=2e-3)
        assert sm[:, press].argmax() == w[:, press].argmax() and sm[:, jaw].argmax() == w[:, jaw].argmax()
    # hold: every peak lasts at least 0.12 s (3 frames) at its height
    h = shaped(hold=0.12)
    top = h[:, press].max()
    assert top == w[:, press].max() and (h[:, press] == top).sum() >= 3 > (w[:, press] == top).sum()
    # viseme shares stay shares: with a gain the silence gives way and every row still sums to 1
    v = viseme_weights(anim)
    vg = shape_curves(v, VISEMES, anim.fps, RigOptions(gain=2.0), rest="sil")
    np.testing.assert_allclose(vg.sum(axis=1), 1.0, atol=1e-12)
    assert vg[:, VISEMES.index("aa")].max() > v[:, VISEMES.index("aa")].max()
    with pytest.raises(AnimationError, match="--rig-scale jawopen: no such shape in the curves written"):
        check_shape_scale(RigOptions(shape_scale=(("jawopen", 2.0),)), ("arkit", "visemes"))
    check_shape_scale(RigOptions(shape_scale=(("viseme_aa", 2.0),), viseme_names="rpm"), ("arkit", "visemes"))
    with pytest.raises(AnimationError, match="--rig-gain -1.0: must be within 0 to 10"):
        RigOptions(gain=-1.0)
    with pytest.raises(AnimationError, match="--rig-scale 'jawOpen': expected NAME=FACTOR"):
        parse_shape_scale("jawOpen")


def test_hold_lengthens_rhubarb_cues(run: RuntimeOutput) -> None:
    """--rig-hold 0.12: no cue shorter than 12 cs, but a tween and what a tween takes from its
    neighbour (at most a third: Rhubarb's timing)."""
    cues = mouth_cues(run.animation, minimum=12)

    def tween(k: int) -> bool:
        return 0 < k < len(cues) - 1 and TWEENS.get((cues[k - 1].value, cues[k + 1].value), ("",))[0] == cues[k].value

    assert any(tween(k) for k in range(len(cues)))
    for k, c in enumerate(cues):
        beside = tween(k - 1) or tween(k + 1)
        assert tween(k) or c.end_cs - c.start_cs >= (8 if beside else 12), c
    assert min(c.end_cs - c.start_cs for c in mouth_cues(run.animation)) < 12  # without the hold


def test_cli_rig_options(tmp_path: Path) -> None:
    (tmp_path / "l.tsv").write_text(APAFULA)
    res = CliRunner().invoke(app, ["animate", str(tmp_path / "l.tsv"), "-t", str(GROUND_TRUTH), "-o", str(tmp_path / "o"),
                                   "--preview", "none", "--export", "arkit,visemes", "--viseme-names", "vrm",
                                   "--rig-gain", "1.5", "--rig-scale", "jawOpen=0.8", "--rig-smooth", "0.08",
                                   "--rig-hold", "0.1"])
    assert res.exit_code == 0, res.output
    assert json.loads((tmp_path / "o" / "l.visemes.json").read_text())["visemes"] == list(VRM_VISEMES)
    res = CliRunner().invoke(app, ["animate", str(tmp_path / "l.tsv"), "-t", str(GROUND_TRUTH), "-o", str(tmp_path / "p"),
                                   "--preview", "none", "--export", "arkit", "--rig-scale", "jaw=2"])
    assert res.exit_code == 2 and "--rig-scale jaw: no such shape in the curves written" in " ".join(res.output.split())
