"""The runtime speaks with an emotion (issue 27 item 3): a table fitted with emotions blended at an
intensity, the lip contacts kept at every intensity (property-tested), the CLI's --emotion and its
errors, and held-out scoring with each trial's own emotion."""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from coartic.cli import app
from coartic.console import EXIT_ERROR
from coartic.emotions import EmotionError, emotion_table, evaluate_by_emotion, table_emotions
from coartic.io.labels import Segments
from coartic.model import Utterance, evaluate_corpus
from coartic.runtime.animate import animate, target_times
from coartic.synthetic_cli import load_generator
from coartic.table import CHANNELS, ParameterTable
from face_helpers import Chromium, shared_chromium

ROOT = Path(__file__).resolve().parents[2]
EMOTIONS = ("joy", "surprise", "sadness", "disgust", "anger", "fear")
REST_GAP_MM = 1.0  # corpus-synthetic/session.toml [geometry] rest_gap: the lips touch at ULO + LLO = -1


def _truth() -> ParameterTable:
    gen: ModuleType = load_generator()
    return gen.emotive_truth(ParameterTable.load(ROOT / "corpus-synthetic" / "ground_truth.json"), gen.load_emotions())


TRUTH = _truth()


def _noisy() -> ParameterTable:
    """As a fit leaves it: deviations on the contacts too (estimation noise, or an expression the data
    gave there), which the runtime must not let open the lips or lift them off the teeth."""
    import copy

    t = copy.deepcopy(TRUTH)
    for ch in ("ULO", "LLO"):
        for i, per in enumerate(t.metadata["emotions"]["channels"][ch]["deviations"].values()):
            for j, ph in enumerate(("p", "b", "m", "f", "v")):
                per[ph] = 1.5 if (i + j) % 2 else -1.5
    return t


NOISY = _noisy()


def reached(table: ParameterTable, ph: str, ch: str) -> float:
    row = table.values[ph][ch]
    return float(row["target"] * (1.0 + row["sigma"]))


def test_table_emotions_and_errors(tmp_path: Path) -> None:
    assert table_emotions(TRUTH) == ("neutral", *EMOTIONS)
    assert emotion_table(TRUTH, None) is TRUTH and emotion_table(TRUTH, "neutral", 0.7) is TRUTH
    with pytest.raises(EmotionError, match="no emotion 'pride'; the table knows neutral, joy, surprise"):
        emotion_table(TRUTH, "pride")
    with pytest.raises(EmotionError, match="--intensity 2.0: expected a number from 0"):
        emotion_table(TRUTH, "joy", 2.0)
    plain = ParameterTable.load(ROOT / "corpus-synthetic" / "ground_truth.json")  # an old table: no emotions
    assert table_emotions(plain) == ()
    with pytest.raises(EmotionError, match="fitted without emotions"):
        emotion_table(plain, "joy")


def test_intensity_scales_the_deviation_trajectory_linearly() -> None:
    """The model is linear in the targets and the emotions share the dynamics: intensity s gives
    F_neutral + s (F_joy − F_neutral) exactly, on every channel whose targets move."""
    seg = Segments(("#", "a", "t", "a", "#"), np.array([0.0, 0.4, 0.57, 0.67, 0.81]),
                   np.array([0.4, 0.57, 0.67, 0.81, 1.1]))
    f = {s: animate(emotion_table(TRUTH, "joy", s), seg, 50.0).channels for s in (0.0, 0.6, 1.0)}
    for ch in ("LR", "ULP", "ULO"):
        np.testing.assert_allclose(f[0.6][ch], f[0.0][ch] + 0.6 * (f[1.0][ch] - f[0.0][ch]), atol=1e-9)
    assert np.ptp(f[1.0]["LR"] - f[0.0]["LR"]) < 1e-9 and f[1.0]["LR"][0] - f[0.0]["LR"][0] == pytest.approx(4.0)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(which=st.sampled_from(["truth", "noisy"]), emotion=st.sampled_from(EMOTIONS), intensity=st.floats(0.0, 1.5), vowel=st.sampled_from("aiu"),
       consonant=st.sampled_from(["p", "b", "m", "f", "v"]), fps=st.sampled_from([25.0, 30.0, 50.0]),
       durations=st.tuples(st.floats(0.05, 0.2), st.floats(0.03, 0.15), st.floats(0.05, 0.2)))
@example(which="truth", emotion="joy", intensity=0.0, vowel="a", consonant="b", fps=25.0,
         durations=(0.125, 0.03, 0.05078125))  # the corner example of the docstring, always tried
def test_lips_close_and_touch_the_teeth_at_every_intensity(which: str, emotion: str, intensity: float, vowel: str,
                                                           consonant: str, fps: float,
                                                           durations: tuple[float, float, float]) -> None:
    """/p b m/ close the lips (ULO + LLO at the neutral closure, past contact) and /f v/ bring the
    lower lip to the neutral contact on the frame nearest their target, whatever the emotion and
    intensity; and so on coartic's face, whose brows, lids, cheeks and lip corners the emotion moves
    too (the FAP file's FAPs, expression included, on coartic.face's mesh): the inner lips touch or
    press along the whole cut at /p b m/ (within 0.1 mm, three of the FAP file's mouth-nose units
    of MNS/1024 = 0.03 mm, below a pixel at any size a player draws the face: beside a lip corner a
    30 ms /b/ at 25 fps, the jaw still at the vowel's 117.7 mm, leaves 0.04 mm there while the
    middle presses 4 mm), the lower lip touches the upper incisors' edge at /f v/
    (within 1.2 mm: neutral speech's own reach over such timings, 1.09 mm at worst over 400 random
    ones; test_face_mesh's utterance, 1 mm). The tables are drawn by name: Hypothesis would print
    a whole table with a failing example."""
    from coartic.face.deform import default_rig
    from coartic.runtime.fap import animation_faps
    from coartic.runtime.pipeline import speaker_face

    ends = np.cumsum([0.4, *durations, 0.3])
    seg = Segments(("#", vowel, consonant, vowel, "#"), np.concatenate([[0.0], ends[:-1]]), ends)
    said = emotion_table(TRUTH if which == "truth" else NOISY, emotion, intensity)
    a = animate(said, seg, fps)
    k = int(min(round(float(target_times(said, seg, "ULO")[2]) * fps), a.n_frames - 1))
    rig = default_rig()
    m = rig.mesh
    pose = rig.pose(rig.weights(animation_faps(a, speaker_face(said), "p"))[k])
    if consonant in ("p", "b", "m"):
        closure = reached(TRUTH, consonant, "ULO") + reached(TRUTH, consonant, "LLO")
        la = a.channels["ULO"][k] + a.channels["LLO"][k]
        assert la == pytest.approx(closure, abs=1e-6) and la + REST_GAP_MM <= 0.0
        assert (pose[m.slit[:, 0], 1] - pose[m.slit[:, 1], 1]).max() <= 0.1  # upper inner lip not above the lower
    else:
        assert a.channels["LLO"][k] == pytest.approx(reached(TRUTH, consonant, "LLO"), abs=1e-6)
        central = m.in_part("upper_teeth") & (np.abs(m.vertices[:, 0]) < 4.0)
        edge = central & (m.vertices[:, 1] < m.vertices[central, 1].min() + 0.3)
        lip = m.in_part("skin") & ~m.upper & (np.abs(m.vertices[:, 0]) < 4.0)
        assert np.linalg.norm(pose[lip][:, None] - pose[edge][None], axis=2).min() < 1.2


def test_scoring_uses_each_utterances_emotion() -> None:
    times = np.arange(0.0, 1.1, 0.01)
    labels = ["#", "a", "b", "a", "#"]
    starts, ends = np.array([0.0, 0.4, 0.57, 0.65, 0.8]), np.array([0.4, 0.57, 0.65, 0.8, 1.1])
    utts = [Utterance(labels, starts, ends, times, f"u{e}", {c: np.zeros_like(times) for c in CHANNELS},
                      {c: np.ones_like(times, dtype=bool) for c in CHANNELS}, {"emotion": e})
            for e in ("neutral", "surprise", "pride")]
    got = evaluate_by_emotion(TRUTH, "JO", utts)
    neutral = evaluate_corpus(TRUTH, "JO", utts[:1])[0]
    np.testing.assert_array_equal(got[0], neutral)
    np.testing.assert_array_equal(got[2], neutral)  # an emotion the table does not know: neutral
    assert got[1].max() - neutral.max() > 1.5  # surprise opens the jaw (+2.5 mm on /a/)


def test_cli_speaks_with_an_emotion(tmp_path: Path) -> None:
    table = tmp_path / "emotive.json"
    TRUTH.save(table)
    labels = tmp_path / "aba.tsv"
    labels.write_text("0.0\t0.4\t#\n0.4\t0.57\ta\n0.57\t0.65\tb\n0.65\t0.8\ta\n0.8\t1.1\t#\n", encoding="utf-8")
    runner = CliRunner()
    outs = {}
    for name, extra in (("neutral", []), ("joy", ["--emotion", "joy", "--intensity", "0.6"])):
        res = runner.invoke(app, ["animate", str(labels), "--table", str(table), "--out", str(tmp_path / name),
                                  "--preview", "none", *extra])
        assert res.exit_code == 0, res.output
        outs[name] = np.genfromtxt(next((tmp_path / name).glob("*.csv")), delimiter=",", names=True)
    np.testing.assert_allclose(outs["joy"]["LR"] - outs["neutral"]["LR"], 0.6 * 4.0, atol=1e-3)
    bad = runner.invoke(app, ["animate", str(labels), "--table", str(table), "--out", str(tmp_path / "x"),
                              "--preview", "none", "--emotion", "pride"])
    assert bad.exit_code == EXIT_ERROR and "the table knows neutral, joy" in bad.output and "Traceback" not in bad.output


def test_emotion_spans_are_read_with_their_errors_named(tmp_path: Path) -> None:
    from coartic.emotions import read_emotion_spans

    f = tmp_path / "spans.tsv"
    f.write_text("# start end emotion intensity\n0.0\t0.5\tjoy\t0.8\n0.6 1.2 anger\n", encoding="utf-8")
    spans = read_emotion_spans(f)
    assert [(s.start, s.end, s.emotion, s.intensity) for s in spans] == [(0.0, 0.5, "joy", 0.8), (0.6, 1.2, "anger", 1.0)]
    for text, message in (("0.0 0.5 joy\n0.4 0.9 fear\n", "line 2: the span starting at 0.4 s overlaps"),
                          ("0.0 x joy\n", "line 1: start, end and intensity must be numbers"),
                          ("0.5 0.2 joy\n", "line 1: a span needs 0 <= start < end"),
                          ("0.0 0.5 joy 3\n", "line 1: intensity '3' is not within 0-1.5"),
                          ("# nothing\n", "no span")):
        f.write_text(text, encoding="utf-8")
        with pytest.raises(EmotionError, match=message):
            read_emotion_spans(f)


def test_spans_blend_the_emotions_over_time_and_keep_the_contacts() -> None:
    """A span over the whole utterance gives the emotion's own trajectory once ramped in; two spans
    switch between emotions through the ramps; the closure of /b/ is the neutral one throughout."""
    from coartic.emotions import EmotionSpan, with_emotion_spans

    seg = Segments(("#", "a", "b", "a", "v", "a", "#"), np.array([0.0, 0.4, 0.56, 0.64, 0.8, 0.9, 1.05]),
                   np.array([0.4, 0.56, 0.64, 0.8, 0.9, 1.05, 1.5]))
    whole = animate(with_emotion_spans(TRUTH, [EmotionSpan(0.0, 10.0, "joy", 0.7)]), seg, 50.0)
    joy = animate(emotion_table(TRUTH, "joy", 0.7), seg, 50.0)
    inside = whole.times >= 0.1  # past the ramp in (0.1 s after the span's start)
    for ch in CHANNELS:
        np.testing.assert_allclose(whole.channels[ch][inside], joy.channels[ch][inside], atol=1e-9)
    two = animate(with_emotion_spans(TRUTH, [EmotionSpan(0.0, 0.7, "surprise"), EmotionSpan(0.7, 2.0, "anger")]),
                  seg, 50.0)
    surprise, anger = (animate(emotion_table(TRUTH, e), seg, 50.0) for e in ("surprise", "anger"))
    early, late = two.times <= 0.55, two.times >= 0.85
    early &= two.times >= 0.1
    np.testing.assert_allclose(two.channels["LR"][early], surprise.channels["LR"][early], atol=1e-9)
    np.testing.assert_allclose(two.channels["LR"][late], anger.channels["LR"][late], atol=1e-9)
    k = int(round(float(target_times(TRUTH, seg, "ULO")[2]) * 50.0))
    closure = reached(TRUTH, "b", "ULO") + reached(TRUTH, "b", "LLO")
    assert two.channels["ULO"][k] + two.channels["LLO"][k] == pytest.approx(closure, abs=1e-6)


def test_expression_outside_the_mouth_in_faps_and_arkit(tmp_path: Path) -> None:
    """Surprise raises the brows and opens the eyes (FAPs 31-36 up, 19/20 below the blinks'), joy
    lifts the cheeks and the lip corners; ARKit gets eyeWide and browInnerUp; neutral has none."""
    from coartic.runtime.fap import FaceUnits, animation_faps
    from coartic.runtime.rigs import ARKIT_NAMES, arkit_weights

    seg = Segments(("#", "a", "b", "a", "#"), np.array([0.0, 0.4, 0.56, 0.64, 0.8]),
                   np.array([0.4, 0.56, 0.64, 0.8, 1.4]))
    faps = {e: animation_faps(animate(emotion_table(TRUTH, e, 0.5) if e else TRUTH, seg, 25.0), FaceUnits(), "x")
            for e in ("", "surprise", "joy")}
    assert not faps[""].mask[:, 30].any()  # neutral: no brow
    for fap in range(31, 37):
        assert (faps["surprise"].column(fap) > 100).all()
    np.testing.assert_array_equal(faps["surprise"].column(19), faps[""].column(19) - 90)  # 0.5 x -180 IRISD
    assert (faps["joy"].column(41) == 90).all()
    assert ((faps["joy"].column(12) + faps["joy"].column(13)) == 90).all()  # 45 each, around the asymmetry
    # disgust's corner asymmetry (ASYMY 1.5 mm, ASYMX 2.0 mm in the truth): the right corner half up,
    # the left half down (MNS), the right half out, the left half in (MW)
    face = FaceUnits()
    dis = animation_faps(animate(emotion_table(TRUTH, "disgust", 1.0), seg, 25.0), face, "x")
    neu = faps[""]
    np.testing.assert_allclose(dis.column(13) - dis.column(12), 1.5 / face.mns, atol=1.0)
    np.testing.assert_allclose((dis.column(7) - neu.column(7)) - (dis.column(6) - neu.column(6)), 2.0 / face.mw,
                               atol=1.0)
    w = arkit_weights(animate(emotion_table(TRUTH, "surprise", 1.0), seg, 25.0))
    assert w[:, ARKIT_NAMES.index("eyeWideLeft")].min() == pytest.approx(0.6)
    assert w[:, ARKIT_NAMES.index("browInnerUp")].min() == pytest.approx(0.8)
    assert arkit_weights(animate(TRUTH, seg, 25.0))[:, ARKIT_NAMES.index("browInnerUp")].max() == 0.0


def test_fap_file_carries_the_high_level_expression(tmp_path: Path) -> None:
    """MPEG-4 FAP 2 beside the low-level FAPs, read back from the file: joy at 0.6 is
    expression_select1 = 1 (joy) at intensity 38 of 63; spans switch the selects through their ramps
    (both emotions of a crossing, the stronger first); neutral speech sends no FAP 2."""
    from coartic.emotions import EmotionSpan, with_emotion_spans
    from coartic.runtime.fap import EXPRESSION_SELECT, FaceUnits, animation_faps, read_fap, write_fap

    seg = Segments(("#", "a", "b", "a", "#"), np.array([0.0, 0.4, 0.56, 0.64, 0.8]),
                   np.array([0.4, 0.56, 0.64, 0.8, 1.6]))
    path = tmp_path / "joy.fap"
    write_fap(path, animation_faps(animate(emotion_table(TRUTH, "joy", 0.6), seg, 25.0), FaceUnits(), "joy"))
    back = read_fap(path)
    assert back.mask[:, 1].all() and back.mask[:, 40].all()  # FAP 2 and the cheeks, every frame
    assert back.expression is not None
    np.testing.assert_array_equal(back.expression, np.tile([1, 38, 0, 0, 0, 0], (back.n_frames, 1)))
    assert (back.column(41) == 108).all()  # the low-level cheeks as before: 0.6 x 180 ENS
    spans = with_emotion_spans(TRUTH, [EmotionSpan(0.0, 0.8, "surprise"), EmotionSpan(0.8, 1.6, "anger", 0.5)])
    write_fap(path, animation_faps(animate(spans, seg, 25.0), FaceUnits(), "spans"))
    e = read_fap(path).expression
    assert e is not None
    assert list(e[10]) == [EXPRESSION_SELECT["surprise"], 63, 0, 0, 0, 0]  # 0.4 s: surprise alone
    assert list(e[30]) == [EXPRESSION_SELECT["anger"], 32, 0, 0, 0, 0]  # 1.2 s: anger at 0.5
    crossing = e[20]  # 0.8 s, the boundary: surprise ramping out (0.5), anger in (0.25)
    assert crossing[[0, 2, 4, 5]].tolist() == [EXPRESSION_SELECT["surprise"], EXPRESSION_SELECT["anger"], 0, 0]
    assert abs(crossing[1] - 31.5) <= 0.5 and abs(crossing[3] - 15.75) <= 0.5
    write_fap(path, animation_faps(animate(TRUTH, seg, 25.0), FaceUnits(), "neutral"))
    assert not read_fap(path).mask[:, 1].any() and read_fap(path).expression is None


browser = pytest.fixture(scope="module")(shared_chromium)


def test_chromium_shows_each_emotion_and_the_closure_stays(tmp_path: Path, browser: Chromium) -> None:
    """The face in headless Chromium at the /a/ of /a b a/: surprise opens the mouth wider than
    neutral and sadness less; at the /b/ the lips touch as in neutral speech for every emotion. The
    whole face in the pause before (no blink yet): surprise raises the brows and shows more of the
    eyes' whites, anger lowers the brows, sadness raises their inner ends and lowers the upper lids
    (coartic.face.deform's brow and lid zones, driven by the FAP file's expression FAPs)."""
    from face_helpers import eyes_of, mouth_opening, upper_face

    from coartic.face.viewer import write_page
    from coartic.runtime.pipeline import animate_file

    labels = tmp_path / "aba.tsv"
    labels.write_text("0.0\t0.5\t#\n0.5\t0.8\ta\n0.8\t0.92\tb\n0.92\t1.1\ta\n1.1\t1.5\t#\n", encoding="utf-8")
    seg = Segments(("#", "a", "b", "a", "#"), np.array([0.0, 0.5, 0.8, 0.92, 1.1]), np.array([0.5, 0.8, 0.92, 1.1, 1.5]))
    opening: dict[str, dict[str, float]] = {}
    face: dict[str, dict[str, float]] = {}
    eyes = None
    for e in ("neutral", "surprise", "sadness", "anger"):
        table = TRUTH if e == "neutral" else emotion_table(TRUTH, e)
        k = np.rint(target_times(table, seg, "LLO") * 25).astype(int)
        animate_file(labels, table, tmp_path / e, fps=25.0, preview="none", gltf=True)
        page = write_page(tmp_path / e)
        # the whole head, at 0.2 s: the first blink comes at 0.6 s (coartic.runtime.fap.BLINK_FIRST_S)
        whole = browser.screenshot(page, tmp_path / f"{e}_face.png", frame=5, face_only=440, size=(440, 440), zoom=1.1)
        eyes = eyes or eyes_of(whole)  # the neutral face's eyes: every face measured in the same band
        face[e] = upper_face(whole, eyes)
        if e == "anger":  # its lips: as neutral's, within a millimetre (EMOTIONS.md); the brows are what it adds here
            continue
        opening[e] = {ph: mouth_opening(browser.screenshot(page, tmp_path / f"{e}_{ph}.png", frame=int(k[i]),
                                                           face_only=400, size=(400, 400), zoom=2.0))
                      for ph, i in (("a", 1), ("b", 2))}
    assert opening["surprise"]["a"] > opening["neutral"]["a"] > opening["sadness"]["a"], opening
    # the closure is the neutral one whatever the emotion (a pixel of anti-aliasing at most)
    assert all(o["b"] == opening["neutral"]["b"] <= 1 for o in opening.values()), opening
    # rows grow downwards: measured 57, 73, 82 pixels (surprise, neutral, anger); sadness's inner
    # thirds 65 against 73, its outer thirds 75 against 74; eye whites 569, 424, 335 pixels
    n = face["neutral"]
    assert face["surprise"]["brow"] < n["brow"] - 8 and face["anger"]["brow"] > n["brow"] + 4, face
    assert face["sadness"]["brow_inner"] < n["brow_inner"] - 4 and face["sadness"]["brow_outer"] > n["brow_outer"] - 1, face
    assert face["surprise"]["sclera"] > 1.2 * n["sclera"] > 1.2 * face["sadness"]["sclera"], face
