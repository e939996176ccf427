"""`coartic speak`: Italian text through the real Festival to WAV, channels and FAP file.

The table is the synthetic session's ground truth (corpus-synthetic/ground_truth.json), whose
bilabials and labiodentals have k_R = 1: their targets must be reached at any speaking rate.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from coartic.cli import app
from coartic.runtime.animate import evaluate, read_channels_csv, target_times
from coartic.runtime.errors import MissingPhonemeError
from coartic.runtime.fap import read_fap
from coartic.runtime.festival import wav_duration
from coartic.runtime.pipeline import speak_text
from coartic.table import ParameterTable

GROUND_TRUTH = Path(__file__).resolve().parents[2] / "corpus-synthetic" / "ground_truth.json"
SENTENCE = "Il babbo mangia la pappa, poi va via."
BILABIAL = ("p", "b", "m")
LABIODENTAL = ("f", "v")

pytestmark = pytest.mark.festival


@pytest.fixture(scope="module")
def table() -> ParameterTable:
    return ParameterTable.load(GROUND_TRUTH)


@pytest.mark.parametrize("fps", [25.0, 30.0])
def test_wav_fap_and_channels_last_as_long(tmp_path: Path, table: ParameterTable, fps: float) -> None:
    result = speak_text(SENTENCE, table, tmp_path, fps=fps, preview="none")
    wav = wav_duration(result.files["wav"])
    faps = read_fap(result.files["fap"])
    times, chans = read_channels_csv(result.files["channels"])
    assert faps.fps == fps and faps.n_frames == times.size == chans["LLO"].size
    assert abs(faps.n_frames / fps - wav) <= 1.0 / fps
    assert abs(result.animation.segments.ends[-1] - wav) < 1e-9  # the last pause runs to the end of the sound
    assert set(result.animation.substitutions) <= {"o", "O"}  # the session has only the vowels i a u


@pytest.mark.slow
@pytest.mark.parametrize("stretch", [1.0, 0.6])
def test_lips_close_and_lower_lip_reaches_teeth_at_any_rate(
    tmp_path: Path, table: ParameterTable, stretch: float
) -> None:
    for ph in BILABIAL:
        assert table.values[ph]["ULO"]["k_r"] == table.values[ph]["LLO"]["k_r"] == 1.0, ph
    for ph in LABIODENTAL:
        assert table.values[ph]["LLO"]["k_r"] == 1.0, ph
    result = speak_text(SENTENCE, table, tmp_path, stretch=stretch, preview="none")
    seg = result.animation.segments
    labels = seg.labels
    assert sum(p in BILABIAL for p in labels) >= 7 and sum(p in LABIODENTAL for p in labels) >= 2
    t_u = target_times(table, seg, "ULO")
    t_l = target_times(table, seg, "LLO")
    ulo = evaluate(table, seg, t_u, ["ULO"])["ULO"]
    llo_at_u = evaluate(table, seg, t_u, ["LLO"])["LLO"]
    llo = evaluate(table, seg, t_l, ["LLO"])["LLO"]
    for i, ph in enumerate(labels):
        if ph in BILABIAL:
            assert t_u[i] == t_l[i]
            closure = reached(table, ph, "ULO") + reached(table, ph, "LLO")
            aperture = ulo[i] + llo_at_u[i]
            assert abs(aperture - closure) <= 0.05, (i, ph, aperture, closure)
        if ph in LABIODENTAL:
            assert abs(llo[i] - reached(table, ph, "LLO")) <= 0.05, (i, ph, llo[i])
    # and the FAP stream shows it: the frame nearest each target time (contact snapping)
    a = result.animation
    frame = np.rint(t_u * a.fps).astype(int)
    for i, ph in enumerate(labels):
        k = min(frame[i], a.n_frames - 1)
        if ph in BILABIAL:
            closure = reached(table, ph, "ULO") + reached(table, ph, "LLO")
            assert abs(a.channels["ULO"][k] + a.channels["LLO"][k] - closure) <= 0.05, (i, ph, k)
        if ph in LABIODENTAL:
            assert abs(a.channels["LLO"][k] - reached(table, ph, "LLO")) <= 0.05, (i, ph, k)
    # faster speech: the same phones in less time
    if stretch != 1.0:
        # and at 25 fps uniform sampling alone would show lips visibly apart (~0.6 mm) on some /p b m/
        plain = speak_text(SENTENCE, table, tmp_path / "plain", stretch=stretch, preview="none",
                           snap_contacts=False).animation
        gaps = [abs(plain.channels["ULO"][frame[i]] + plain.channels["LLO"][frame[i]]
                    - reached(table, ph, "ULO") - reached(table, ph, "LLO"))
                for i, ph in enumerate(labels) if ph in BILABIAL]
        assert max(gaps) > 0.3
        normal = speak_text(SENTENCE, table, tmp_path / "normal", preview="none")
        assert normal.animation.segments.labels == labels
        assert seg.ends[-2] < 0.7 * normal.animation.segments.ends[-2]


def reached(table: ParameterTable, phoneme: str, channel: str) -> float:
    """What a k_R = 1 phoneme reaches at its target time: T S(0) = T (1 + sigma) (MODEL.md §3, item 3)."""
    row = table.values[phoneme][channel]
    return row["target"] * (1.0 + row["sigma"])


def _without(table: ParameterTable, phoneme: str, path: Path) -> Path:
    del table.values[phoneme]
    table.reasons.pop(phoneme, None)
    table.uncertainty.pop(phoneme, None)
    table.save(path)
    return path


def test_missing_phoneme_is_named(tmp_path: Path) -> None:
    small = ParameterTable.load(_without(ParameterTable.load(GROUND_TRUTH), "p", tmp_path / "no_p.json"))
    with pytest.raises(MissingPhonemeError,
                       match=r"no_p.json has no phoneme 'p', needed by segment 4 .*Festival phone 'p' of 'la pappa'"):
        speak_text("la pappa", small, tmp_path / "o", preview="none")


def test_cli_speak_errors_exit_nonzero_without_traceback(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    runner = CliRunner()
    table = _without(ParameterTable.load(GROUND_TRUTH), "p", tmp_path / "no_p.json")
    cases = [
        (["speak", "  ", "-t", str(table), "-o", str(tmp_path / "a")], "empty text"),
        (["speak", "la pappa", "-t", str(table), "-o", str(tmp_path / "b")], "has no phoneme 'p'"),
        (["speak", "poi", "--strict", "-t", str(GROUND_TRUTH), "-o", str(tmp_path / "c"), "--preview", "none"],
         "has no phoneme 'O'"),
        (["speak", "ciao", "-t", str(tmp_path / "nothere.json"), "-o", str(tmp_path / "d")], "nothere.json"),
    ]
    for args, needle in cases:
        res = runner.invoke(app, args)
        assert res.exit_code == 2, (args, res.output)
        assert needle in res.output and "Traceback" not in res.output, res.output
    monkeypatch.setenv("PATH", str(tmp_path))
    res = runner.invoke(app, ["speak", "ciao", "-t", str(GROUND_TRUTH), "-o", str(tmp_path / "e")])
    assert res.exit_code == 2 and "'festival' not found on PATH" in res.output


def test_speak_output_animates_again_to_the_same_frames(tmp_path: Path, table: ParameterTable) -> None:
    from coartic.runtime.pipeline import animate_file

    spoken = speak_text("Vado a Bologna.", table, tmp_path / "s", preview="none")
    again = animate_file(tmp_path / "s" / "segments.tsv", table, tmp_path / "a", preview="none")
    assert again.animation.segments.labels == spoken.animation.segments.labels
    assert again.animation.substitutions == spoken.animation.substitutions
    for c, y in spoken.animation.channels.items():
        np.testing.assert_array_equal(again.animation.channels[c], y)
    np.testing.assert_array_equal(again.faps.values, spoken.faps.values)


def test_accented_text_gives_an_ascii_fap_name(tmp_path: Path, table: ParameterTable) -> None:
    result = speak_text("Perché no?", table, tmp_path, preview="none")
    assert result.files["fap"].name == "Perche_no.fap"
    assert read_fap(result.files["fap"]).name == "Perche_no"


def test_bad_preview_format_is_refused_before_festival_runs(tmp_path: Path, table: ParameterTable) -> None:
    from coartic.runtime.errors import AnimationError

    with pytest.raises(AnimationError, match="preview must be one of gif, mp4, none, got 'avi'"):
        speak_text("ciao", table, tmp_path / "o", preview="avi")
    assert not (tmp_path / "o").exists()


def test_mp4_preview_carries_the_speech_in_sync(tmp_path: Path, table: ParameterTable) -> None:
    import json
    import subprocess

    result = speak_text("Viva la mamma!", table, tmp_path, fps=25.0, preview="mp4")
    probe = subprocess.run(["ffprobe", "-v", "error", "-show_streams", "-of", "json", str(result.files["preview"])],
                           capture_output=True, text=True, check=True)
    streams = {s["codec_type"]: s for s in json.loads(probe.stdout)["streams"]}
    assert set(streams) == {"video", "audio"}
    assert int(streams["video"]["nb_frames"]) == result.animation.n_frames
    assert result.utterance is not None
    video = float(streams["video"]["duration"])
    audio = float(streams["audio"]["duration"])
    assert abs(video - result.utterance.duration) <= 1 / 25 and abs(audio - result.utterance.duration) <= 1 / 25


def test_cli_speak_writes_everything(tmp_path: Path) -> None:
    res = CliRunner().invoke(app, ["speak", "Viva la mamma!", "-t", str(GROUND_TRUTH), "-o", str(tmp_path),
                                   "--fps", "25", "--stretch", "0.8"])
    assert res.exit_code == 0, res.output
    names = {p.name for p in tmp_path.iterdir()}
    # the WAV under the FAP file's name: Greta loads NAME.fap with NAME.wav
    assert {"Viva_la_mamma.wav", "channels.csv", "Viva_la_mamma.fap", "segments.tsv", "channels.png", "strip.png",
            "preview.gif"} <= names
    res = CliRunner().invoke(app, ["speak", "Viva la mamma!", "-t", str(GROUND_TRUTH), "-o", str(tmp_path / "g"),
                                   "--preview", "none", "--fap-name", "viva", "--gltf"])
    assert res.exit_code == 0, res.output
    assert {"viva.wav", "viva.fap", "viva.glb"} <= {p.name for p in (tmp_path / "g").iterdir()}


def test_speak_into_a_used_directory(tmp_path: Path) -> None:
    """Other text into the same --out is refused (it would mix two runs) unless --force."""
    out = tmp_path / "speech"

    def speak(text: str, *extra: str) -> tuple[int, str]:
        r = CliRunner().invoke(app, ["speak", text, "-t", str(GROUND_TRUTH), "-o", str(out), "--preview", "none", *extra])
        return r.exit_code, r.output.replace("\n", " ")

    assert speak("Ciao mamma.")[0] == 0
    first = sorted(p.name for p in out.iterdir())
    code, text = speak("Viva la pappa.")
    assert code == 2 and "holds coartic speak text Ciao mamma." in text, text
    assert sorted(p.name for p in out.iterdir()) == first
    code, text = speak("Viva la pappa.", "--force")
    assert code == 0, text
    assert "Viva_la_pappa.fap" in {p.name for p in out.iterdir()} and "Ciao_mamma.fap" not in {p.name for p in out.iterdir()}
