"""Label files → channels, FAP file, preview (coartic.runtime.animate, pipeline, preview)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from coartic.cli import app
from coartic.io.errors import DataError
from coartic.io.labels import Segments
from coartic.runtime.animate import (
    animate,
    evaluate,
    frame_times,
    neutral_posture,
    read_channels_csv,
    substitute,
    target_times,
)
from coartic.runtime.errors import AnimationError, MissingPhonemeError
from coartic.runtime.fap import FaceUnits, read_fap
from coartic.runtime.pipeline import animate_file
from coartic.runtime.preview import mouth_shape
from coartic.table import CHANNELS, PARAMETERS, ChannelSettings, ParameterTable

REST = {"ULO": 0.0, "LLO": 0.0, "ULP": 98.0, "LLP": 95.0, "LR": 50.0, "JO": 115.0}
TARGETS = {
    "#": REST,
    "a": {"ULO": 2.5, "LLO": 12.0, "ULP": 97.5, "LLP": 94.0, "LR": 52.0, "JO": 125.0},
    "i": {"ULO": 1.5, "LLO": 5.0, "ULP": 96.5, "LLP": 93.5, "LR": 55.0, "JO": 117.0},
    "p": {"ULO": -2.0, "LLO": -2.5, "ULP": 98.3, "LLP": 95.5, "LR": 49.5, "JO": 116.0},
    "f": {"ULO": 0.8, "LLO": -1.0, "ULP": 98.2, "LLP": 92.5, "LR": 50.5, "JO": 115.5},
}
K_R = {"#": 1.0, "a": 0.4, "i": 0.4, "p": 1.0, "f": 1.0}


def make_table(phonemes: tuple[str, ...] = ("#", "a", "i", "p", "f")) -> ParameterTable:
    values: dict[str, dict[str, dict[str, float]]] = {}
    for ph in phonemes:
        values[ph] = {}
        for ch in CHANNELS:
            row = dict(target=TARGETS[ph][ch], alpha=1.0 if ph in "#a" else 2.0, theta_bw=20.0, theta_fw=20.0,
                       c_bw=1.0, c_fw=1.0, k_r=K_R[ph], sigma=0.0, psi=100.0, delta=0.0)
            values[ph][ch] = {p: float(row[p]) for p in PARAMETERS}
    table = ParameterTable(variant="modified", channels={c: ChannelSettings(reference_phoneme="a") for c in CHANNELS},
                           values=values, source="fixture.json")
    table.validate()
    return table


LABELS = "start\tend\tlabel\n0.0\t0.30\tsil\n0.30\t0.45\ta\n0.45\t0.53\tp\n0.53\t0.68\ti\n0.68\t0.77\tf\n0.77\t0.92\ta\n0.92\t1.20\tsil\n"


@pytest.fixture()
def labels(tmp_path: Path) -> Path:
    path = tmp_path / "apifa.tsv"
    path.write_text(LABELS)
    return path


def test_frame_times() -> None:
    t = frame_times(1.0, 25.0)
    assert t.size == 25 and t[1] == 0.04
    assert frame_times(1.21, 10.0).size == 12
    with pytest.raises(AnimationError, match="frame rate"):
        frame_times(1.0, 0.0)


def test_animate_file_writes_consistent_outputs(tmp_path: Path, labels: Path) -> None:
    out = tmp_path / "out"
    result = animate_file(labels, make_table(), out, fps=50.0, preview="gif")
    a = result.animation
    assert a.n_frames == 60 and a.duration == pytest.approx(1.2)
    for key in ("channels", "fap", "segments", "plot", "strip", "preview"):
        assert result.files[key].exists(), key
    assert not list(out.glob(".*.tmp-*"))
    times, chans = read_channels_csv(result.files["channels"])
    np.testing.assert_array_equal(times, a.times)
    for c in CHANNELS:
        np.testing.assert_array_equal(chans[c], a.channels[c])
    faps = read_fap(result.files["fap"])
    assert faps.n_frames == a.n_frames and faps.fps == 50.0 and faps.name == "apifa"
    # the first frames are the rest posture: the neutral face, every FAP zero
    assert np.all(faps.values[0] == 0)
    # open /a/ at its target time: the jaw and lower lip are down, so open_jaw > 0, raise_b_midlip < 0
    k = int(round(0.375 * 50))
    fapu = FaceUnits().mns
    assert faps.column(3)[k] == round((a.channels["JO"][k] - 115.0) / fapu) > 0
    assert faps.column(5)[k] == round(-a.channels["LLO"][k] / fapu) < 0
    with Image.open(result.files["preview"]) as gif:
        assert getattr(gif, "n_frames") == a.n_frames  # animated images only
    assert (out / "segments.tsv").read_text().splitlines()[1].split("\t") == ["0.0", "0.3", "#", "#", "sil"]


def test_the_faps_are_computed_once_for_every_exporter(tmp_path: Path, labels: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    # the FAP file, the glTF, the VRML and the result all take the one FAP sequence (issue 28: it
    # was computed up to 4 times per run, the tongue animated through the model each time)
    import coartic.runtime.tongue as tongue

    calls = []
    real = tongue.tongue_channels
    monkeypatch.setattr(tongue, "tongue_channels", lambda a: calls.append(a) or real(a))
    result = animate_file(labels, make_table(), tmp_path / "out", preview="none", gltf=True, vrml=True)
    assert len(calls) == 1 and calls[0] is result.animation
    assert {"fap", "gltf", "vrml"} <= set(result.files)
    np.testing.assert_array_equal(read_fap(result.files["fap"]).values, result.faps.values)
    # the ARKit weights of the glTF's morph set and of the curves: computed once too
    import coartic.runtime.expression as expression

    weighed = []
    arkit = expression.expression_arkit
    monkeypatch.setattr(expression, "expression_arkit", lambda a: weighed.append(a) or arkit(a))
    result = animate_file(labels, make_table(), tmp_path / "arkit", preview="none", gltf=True, gltf_morphs="arkit",
                          exports="arkit")
    assert len(weighed) == 1 and {"gltf", "arkit_csv"} <= set(result.files)


def test_resistant_targets_are_reached(labels: Path) -> None:
    table = make_table()
    from coartic.io.labelmap import LabelMap
    from coartic.io.labels import read_labels

    seg = LabelMap.model().apply(read_labels(labels))
    for ch in ("ULO", "LLO"):
        t = target_times(table, seg, ch)
        y = evaluate(table, seg, t, [ch])[ch]
        for i, ph in enumerate(seg.labels):
            if ph in ("p", "f"):
                assert y[i] == pytest.approx(TARGETS[ph][ch], abs=1e-9), (ph, ch)
            if ph == "a":
                assert abs(y[i] - TARGETS[ph][ch]) > 0.01  # k_R < 1: the vowel yields


def test_missing_phoneme_names_file_line_and_phoneme(tmp_path: Path, labels: Path) -> None:
    with pytest.raises(MissingPhonemeError) as err:
        animate_file(labels, make_table(("#", "a", "i", "p")), tmp_path / "o", preview="none")
    msg = str(err.value)
    assert "fixture.json has no phoneme 'f'" in msg and "segment 5" in msg and "apifa.tsv, line 6" in msg


def test_table_without_pause_has_no_neutral_face() -> None:
    with pytest.raises(MissingPhonemeError, match="no pause phoneme '#'"):
        neutral_posture(make_table(("a", "i", "p", "f")))


def test_substitute_uses_fallbacks_in_order() -> None:
    seg = Segments(("#", "o", "p", "e", "#"), np.array([0, .1, .2, .3, .4]), np.array([.1, .2, .3, .4, .5]))
    new, used = substitute(seg, make_table(), CHANNELS, {"o": ("O", "u", "a"), "e": ("E", "i")})
    assert new.labels == ("#", "a", "p", "i", "#") and used == {"o": "a", "e": "i"}
    with pytest.raises(MissingPhonemeError, match="no phoneme 'o'"):
        animate(make_table(), substitute(seg, make_table(), CHANNELS, {})[0], 25.0)


def test_mouth_geometry() -> None:
    rest = mouth_shape(REST, REST)
    assert rest.aperture == 0.0
    shut = mouth_shape(TARGETS["p"], REST)  # pressed lips meet, they do not cross
    assert shut.aperture == 0.0
    np.testing.assert_allclose(shut.upper_inner[:, 1], shut.lower_inner[:, 1])
    open_a = mouth_shape(TARGETS["a"], REST)
    assert open_a.aperture == pytest.approx(2.5 + 12.0)
    assert open_a.upper_inner[:, 0].max() == pytest.approx(26.0)  # corners at ±LR/2
    assert open_a.chin[:, 1].min() == pytest.approx(rest.chin[:, 1].min() - 10.0)  # the jaw dropped 10 mm


def test_mp4_preview(tmp_path: Path, labels: Path) -> None:
    result = animate_file(labels, make_table(), tmp_path / "o", fps=10.0, preview="mp4")
    head = result.files["preview"].read_bytes()[:12]
    assert head[4:8] == b"ftyp"


def test_cli_animate_and_its_errors(tmp_path: Path, labels: Path) -> None:
    table = tmp_path / "table.json"
    make_table().save(table)
    runner = CliRunner()
    ok = runner.invoke(app, ["animate", str(labels), "--table", str(table), "--out", str(tmp_path / "o"),
                             "--fps", "20", "--preview", "none"])
    assert ok.exit_code == 0, ok.output
    assert read_fap(tmp_path / "o" / "apifa.fap").n_frames == 24
    small = tmp_path / "small.json"
    make_table(("#", "a", "i", "p")).save(small)
    bad = runner.invoke(app, ["animate", str(labels), "--table", str(small), "--out", str(tmp_path / "o2")])
    assert bad.exit_code == 2
    assert "has no phoneme 'f'" in bad.output and "Traceback" not in bad.output
    garbled = tmp_path / "garbled.tsv"
    garbled.write_text("0.0\t0.3\tsil\n0.2\t0.1\ta\n")
    bad = runner.invoke(app, ["animate", str(garbled), "--table", str(table), "--out", str(tmp_path / "o3")])
    assert bad.exit_code == 2 and "garbled.tsv" in bad.output and "Traceback" not in bad.output


def test_label_reader_errors_pass_through(tmp_path: Path) -> None:
    with pytest.raises(DataError):
        animate_file(tmp_path / "missing.TextGrid", make_table(), tmp_path / "o")


def test_contact_snapping_keeps_short_closures_on_a_frame() -> None:
    # fast /apa/: a 30 ms /p/ between two 25 fps frames (0.44 and 0.48 s), 50 ms vowels
    seg = Segments(("#", "a", "p", "a", "#"), np.array([0.0, 0.4, 0.45, 0.48, 0.53]),
                   np.array([0.4, 0.45, 0.48, 0.53, 1.0]))
    table = make_table()
    closure = TARGETS["p"]["ULO"] + TARGETS["p"]["LLO"]
    plain = animate(table, seg, 25.0, snap_contacts=False)
    snapped = animate(table, seg, 25.0)
    la_plain = plain.channels["ULO"] + plain.channels["LLO"]
    la_snap = snapped.channels["ULO"] + snapped.channels["LLO"]
    assert la_plain.min() - closure > 0.5  # uniform sampling shows the lips apart
    k = int(np.argmin(la_snap))
    assert k == 12 and la_snap[k] == pytest.approx(closure, abs=1e-9)  # 0.48 s, 15 ms from t_p = 0.465 s
    assert snapped.sample_times["ULO"][k] == pytest.approx(0.465)
    # only frames next to k_R = 1 targets move, each by at most half a frame
    moved = snapped.sample_times["LLO"] != snapped.times
    assert np.all(np.abs(snapped.sample_times["LLO"] - snapped.times) <= 0.02 + 1e-12)
    assert 0 < moved.sum() <= 3  # /p/ and the two pauses
    np.testing.assert_array_equal(la_plain[~moved], la_snap[~moved])


REAL_LABELS = Path(__file__).resolve().parents[1] / "data" / "realdata" / "emu-ema-german" / "derived"
GROUND_TRUTH = Path(__file__).resolve().parents[2] / "corpus-synthetic" / "ground_truth.json"


def test_real_german_labels_with_fallbacks_and_strict(tmp_path: Path) -> None:
    labels = REAL_LABELS / "dfgspp_mo1_prosody_0024_Segment.tsv"
    table = ParameterTable.load(GROUND_TRUTH)
    result = animate_file(labels, table, tmp_path / "o", fps=25.0, label_map="german_sampa", preview="none")
    a = result.animation
    assert a.n_frames == round(a.segments.ends[-1] * 25)
    assert "e" in a.substitutions  # German schwa -> /e/, which the i-a-u session lacks
    assert set(a.segments.labels) <= set(table.values)
    # the labelled /m/ and /b/ close the lips on their nearest frame (k_R = 1, contact snapping)
    t = target_times(table, a.segments, "ULO")
    for i, ph in enumerate(a.segments.labels):
        if ph in ("p", "b", "m"):
            k = int(round(t[i] * 25))
            closure = sum(table.values[ph][c]["target"] * (1 + table.values[ph][c]["sigma"]) for c in ("ULO", "LLO"))
            assert a.channels["ULO"][k] + a.channels["LLO"][k] == pytest.approx(closure, abs=1e-6)
    with pytest.raises(MissingPhonemeError, match=r"has no phoneme 'O', needed by segment 3 of .*0024_Segment.tsv, line 4"):
        animate_file(labels, table, tmp_path / "s", label_map="german_sampa", preview="none", strict=True)


def test_fapu_is_the_speakers_face(tmp_path: Path, labels: Path) -> None:
    from coartic.runtime.pipeline import speaker_face

    table = make_table()
    table.values["#"]["LR"]["target"] = 48.0  # this speaker's mouth at rest is 48 mm wide
    face = speaker_face(table)
    assert (face.mns_mm, face.mw_mm) == (30.0, 48.0)
    assert speaker_face(table, mns_mm=28.0, mw_mm=52.0) == FaceUnits(28.0, 52.0)
    result = animate_file(labels, table, tmp_path / "o", preview="none")
    d_lr = result.animation.channels["LR"] - 48.0
    np.testing.assert_array_equal(result.faps.column(6), np.rint(d_lr / 2 / (48.0 / 1024)).astype(np.int64))


TEXTGRID = '''File type = "ooTextFile"
Object class = "TextGrid"

xmin = 0
xmax = 1.2
tiers? <exists>
size = 1
item []:
    item [1]:
        class = "IntervalTier"
        name = "phones"
        xmin = 0
        xmax = 1.2
        intervals: size = 7
''' + "".join(
    f'        intervals [{k + 1}]:\n            xmin = {s}\n            xmax = {e}\n            text = "{lab}"\n'
    for k, (s, e, lab) in enumerate([(0.0, 0.3, ""), (0.3, 0.45, "a"), (0.45, 0.53, "p"), (0.53, 0.68, "i"),
                                     (0.68, 0.77, "f"), (0.77, 0.92, "a"), (0.92, 1.2, "sil")])
)
HTK = "".join(f"{round(s * 1e7)} {round(e * 1e7)} {lab}\n" for s, e, lab in
              [(0.0, 0.3, "sil"), (0.3, 0.45, "a"), (0.45, 0.53, "p"), (0.53, 0.68, "i"), (0.68, 0.77, "f"),
               (0.77, 0.92, "a"), (0.92, 1.2, "sil")])


def test_textgrid_lab_and_tsv_animate_alike(tmp_path: Path, labels: Path) -> None:
    (tmp_path / "apifa.TextGrid").write_text(TEXTGRID)
    (tmp_path / "apifa.lab").write_text(HTK)
    ref = animate_file(labels, make_table(), tmp_path / "tsv", preview="none")
    for name in ("apifa.TextGrid", "apifa.lab"):
        other = animate_file(tmp_path / name, make_table(), tmp_path / name.replace(".", "_"), preview="none")
        assert other.animation.segments.labels == ref.animation.segments.labels
        np.testing.assert_array_equal(other.faps.values, ref.faps.values)


def test_interrupted_preview_leaves_complete_outputs_and_no_partial_file(tmp_path: Path, labels: Path) -> None:
    from rich.progress import Progress, TaskID

    class Interrupt(Progress):
        def advance(self, task_id: TaskID, advance: float = 1) -> None:
            if self.tasks[0].completed >= 3:
                raise KeyboardInterrupt
            super().advance(task_id, advance)

    out = tmp_path / "o"
    with pytest.raises(KeyboardInterrupt), Interrupt(disable=True) as progress:
        animate_file(labels, make_table(), out, preview="gif", progress=progress)
    assert read_fap(out / "apifa.fap").n_frames == 30
    assert (out / "channels.csv").exists() and (out / "strip.png").exists()
    assert not (out / "preview.gif").exists() and not list(out.glob(".*.tmp-*"))


def test_long_gif_is_refused_up_front(tmp_path: Path, labels: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import coartic.runtime.preview as preview

    monkeypatch.setattr(preview, "GIF_MAX_FRAMES", 10)
    with pytest.raises(AnimationError, match=r"GIF of 30 frames .*\(--preview mp4\)"):
        animate_file(labels, make_table(), tmp_path / "o", preview="gif")
    assert not (tmp_path / "o" / "preview.gif").exists()


FITTED = Path(__file__).parents[1] / "data/fitted/quick_llo_table.json"


def test_fitted_table_snaps_contacts_and_animates_its_one_channel(tmp_path: Path) -> None:
    # a table from `coartic fit` (tests/data/fitted): LLO only, k_R of /p f/ = 0.9999999999999999
    table = ParameterTable.load(FITTED)
    assert 0.999 < table.values["p"]["LLO"]["k_r"] < 1.0
    labels = tmp_path / "apa.tsv"
    labels.write_text("0\t0.2\t#\n0.2\t0.35\ta\n0.35\t0.41\tp\n0.41\t0.6\ta\n0.6\t0.8\t#\n")
    res = CliRunner().invoke(app, ["animate", str(labels), "--table", str(FITTED), "--out",
                                   str(tmp_path / "o"), "--preview", "none"])
    assert res.exit_code == 0, res.output
    assert "ULO, ULP, LLP, LR, JO: held at rest" in " ".join(res.output.split())
    result = animate_file(labels, table, tmp_path / "o2", fps=25.0, preview="none")
    a = result.animation
    assert a.at_rest == ("ULO", "ULP", "LLP", "LR", "JO") and a.modelled == ["LLO"]
    # the /p/ target (k_R at its bound) is shown on its nearest frame: the lower lip reaches it
    i = a.segments.labels.index("p")
    t_p = target_times(table, a.segments, "LLO")[i]
    k = int(round(t_p * 25.0))
    assert "LLO" in a.sample_times and a.sample_times["LLO"][k] == t_p
    row = table.values["p"]["LLO"]
    assert a.channels["LLO"][k] == pytest.approx(row["target"] * (1 + row["sigma"]), abs=1e-6)
    # channels at rest are the neutral face: zero FAPs; only LLO is written as model output
    faps = read_fap(result.files["fap"])
    assert np.all(faps.column(3) == 0) and np.all(faps.column(17) == 0) and np.any(faps.column(5) != 0)
    times, chans = read_channels_csv(result.files["channels"])
    assert list(chans) == ["LLO"]


def test_recorded_label_map_is_applied_by_trajectories_and_animate(tmp_path: Path) -> None:
    from coartic.io.labelmap import LabelMap
    from coartic.model import ModelInputError, trajectories

    table = make_table()
    LabelMap.from_dict({"AA1": "a", "IY0": "i", "P": "p", "F": "f"}, "arpa.json").record_in(table)
    starts, ends = [0.0, 0.3, 0.45, 0.53, 0.68], [0.3, 0.45, 0.53, 0.68, 0.9]
    times = np.linspace(0.0, 0.9, 19)
    corpus = trajectories(table, ["sil", "AA1", "P", "IY0", "sil"], starts, ends, times)
    model = trajectories(table, ["#", "a", "p", "i", "#"], starts, ends, times,
                         label_map=LabelMap.identity(table.phonemes, "phonemes"))
    for c in CHANNELS:
        np.testing.assert_array_equal(corpus[c], model[c])
    with pytest.raises(ModelInputError, match=r"label 'a' \(segment 2\) has no mapping in the label map recorded in fixture\.json \(arpa\.json\)"):
        trajectories(table, ["#", "a", "p", "i", "#"], starts, ends, times)
    labels = tmp_path / "arpa.tsv"
    labels.write_text("0\t0.3\tsil\n0.3\t0.45\tAA1\n0.45\t0.53\tP\n0.53\t0.68\tIY0\n0.68\t0.9\tsil\n")
    a = animate_file(labels, table, tmp_path / "o", fps=25.0, preview="none").animation
    # the final pause's first FINAL_PAUSE_S is the model's pause, the rest a second one (held at rest)
    assert a.segments.labels == ("#", "a", "p", "i", "#", "#")


def test_table_without_runtime_channels_is_named(tmp_path: Path, labels: Path) -> None:
    table = make_table()
    table.channels = {"LA": table.channels["LLO"]}
    table.values = {ph: {"LA": per["LLO"]} for ph, per in table.values.items()}
    with pytest.raises(MissingPhonemeError, match=r"fixture\.json has none of the channels ULO, LLO, ULP, LLP, "
                                                  r"LR, JO \(it has LA\): nothing to animate"):
        animate_file(labels, table, tmp_path / "o", preview="none")


def test_animate_speaks_as_the_tables_speaker(tmp_path: Path, labels: Path) -> None:
    """--speaker maps the modelled channels and the neutral face by the table's a_s + b_s·F; an
    unknown speaker, or a table fitted without speakers, is an error."""
    from coartic.speakers import SpeakerError

    table = make_table()
    plain = animate_file(labels, table, tmp_path / "plain", fps=25.0, preview="none")
    with pytest.raises(SpeakerError, match="fitted without speakers"):
        animate_file(labels, table, tmp_path / "x", fps=25.0, preview="none", speaker="s2")
    table.metadata["speakers"] = {"mode": "offset_scale", "column": "speaker", "coefficients": {
        c: {"s1": {"offset_mm": 0.0, "scale": 1.0}, "s2": {"offset_mm": 0.5, "scale": 1.2}} for c in CHANNELS}}
    s2 = animate_file(labels, table, tmp_path / "s2", fps=25.0, preview="none", speaker="s2")
    for c in CHANNELS:
        np.testing.assert_allclose(s2.animation.channels[c], 0.5 + 1.2 * plain.animation.channels[c], rtol=1e-12)
    # the strip of mouth shapes is the speaker's too: its faces differ from the table's own
    from coartic.runtime.pipeline import speaker_mapping
    from coartic.runtime.preview import render_strip

    render_strip(s2.animation, table, tmp_path / "own.png", speaker=speaker_mapping(table, "s2"))
    render_strip(s2.animation, table, tmp_path / "population.png")
    assert (tmp_path / "own.png").read_bytes() != (tmp_path / "population.png").read_bytes()
    # the FAPs are measured from s2's own neutral face (a + b·rest): the first frames stay at zero
    assert np.all(read_fap(s2.files["fap"]).values[0] == 0)
    with pytest.raises(SpeakerError, match="no speaker 's9'; the table knows s1, s2"):
        animate_file(labels, table, tmp_path / "y", fps=25.0, preview="none", speaker="s9")
    path = tmp_path / "table.json"
    table.save(path)
    ok = CliRunner().invoke(app, ["animate", str(labels), "--table", str(path), "--out", str(tmp_path / "cli"),
                                  "--preview", "none", "--speaker", "s2"])
    assert ok.exit_code == 0, ok.output
    bad = CliRunner().invoke(app, ["animate", str(labels), "--table", str(path), "--out", str(tmp_path / "cli2"),
                                   "--preview", "none", "--speaker", "s9"])
    assert bad.exit_code == 2 and "s1, s2" in bad.output and "Traceback" not in bad.output
