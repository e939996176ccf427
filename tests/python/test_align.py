"""coartic align: a recording and its transcript → phones in time, on the real German EMA recordings
(MAUS labels as the reference), and every bad input refused or flagged."""

from __future__ import annotations

import re
import wave
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from coartic.align.accuracy import boundary_accuracy
from coartic.align.aligner import align_recording, read_transcript, textgrid_text
from coartic.align.audio import read_recording
from coartic.align.errors import AlignError, AlignWarning
from coartic.align.synthesis import ipa_phone, split_text
from coartic.cli import app
from coartic.io.labelmap import LabelMap
from coartic.io.labels import read_labels

pytestmark = pytest.mark.festival

DATA = Path(__file__).parents[1] / "data/realdata/emu-ema-german/derived"
WAV = DATA / "dfgspp_mo1_prosody_0020.wav"
LABELS = DATA / "dfgspp_mo1_prosody_0020_Segment.tsv"
# written from the bundle's MAUS phones (z i: a: 6 b aI t @ t I n aI n 6 k n aI p @ a l s k E l n @ r I n)
TEXT = "Sie arbeitete in einer Kneipe als Kellnerin."
OTHER = "Der Hund bellt laut im Garten hinter dem Haus."


def _write_wav(path: Path, samples: np.ndarray, rate: int = 16000) -> Path:
    with wave.open(str(path), "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(rate)
        w.writeframes((np.clip(samples, -1, 1) * 32767).astype("<i2").tobytes())
    return path


def test_german_alignment_against_maus() -> None:
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error", AlignWarning)  # a confident alignment warns of nothing
        alignment = align_recording(WAV, TEXT, "de")
    reference = LabelMap.builtin("german_sampa").apply(read_labels(LABELS))
    acc = boundary_accuracy(reference, alignment.segments())
    # measured 28 ms median, 61 % within 40 ms (docs/ALIGN.md); a broken warp is hundreds of ms off
    assert acc.median_ms < 45 and acc.within(40) > 0.5, acc.summary()
    assert len(acc.errors) >= 28
    assert alignment.words == ("Sie", "arbeitete", "in", "einer", "Kneipe", "als", "Kellnerin")
    assert alignment.phonemes[0] == alignment.phonemes[-1] == "#"  # the silence before and after
    assert float(alignment.ends[-1]) == pytest.approx(read_recording(WAV).duration)


def test_wrong_transcript_is_flagged() -> None:
    with pytest.warns(AlignWarning, match="matches the transcript poorly"):
        alignment = align_recording(WAV, OTHER, "de")
    assert any("poorly" in w for w in alignment.warnings)


def test_silence_is_refused(tmp_path: Path) -> None:
    quiet = _write_wav(tmp_path / "quiet.wav", 1e-4 * np.random.default_rng(0).standard_normal(32000))
    with pytest.raises(AlignError, match=r"quiet\.wav: no speech"):
        align_recording(quiet, TEXT, "de")


def test_corrupt_wav_is_refused(tmp_path: Path) -> None:
    bad = tmp_path / "bad.wav"
    bad.write_bytes(b"RIFF\x10\x00\x00\x00WAVEfmt garbage")
    with pytest.raises(AlignError, match=r"bad\.wav: not a readable WAV.*ffmpeg"):
        align_recording(bad, TEXT, "de")


def test_three_hour_recording_is_refused_from_its_header(tmp_path: Path) -> None:
    long = tmp_path / "long.wav"
    _write_wav(long, np.zeros(10))
    n = 3 * 3600 * 16000
    with open(long, "r+b") as f:  # a sparse 3-hour WAV: the header says so, the disk holds no samples
        f.seek(4)
        f.write((36 + 2 * n).to_bytes(4, "little"))
        f.seek(40)
        f.write((2 * n).to_bytes(4, "little"))
        f.truncate(44 + 2 * n)
    with pytest.raises(AlignError, match=r"lasts 3:00:00, more than the 1:00:00 .*--max-duration"):
        align_recording(long, TEXT, "de")


def test_other_language_is_flagged() -> None:
    """German said and written, aligned as English: the words are not in PocketSphinx's English
    dictionary (said, with the language asked about), and Festival aligns instead (said)."""
    with pytest.warns(AlignWarning) as record:
        alignment = align_recording(WAV, TEXT, "en")
    said = " ".join(str(w.message) for w in record)
    assert "dictionary (cmudict-en-us) has no 'arbeitete'" in said and "aligned by synthesis with Festival" in said
    assert "are not English words: is the transcript in English (--lang)?" in said
    assert alignment.method.startswith("alignment by synthesis: festival")


def test_english_wrong_transcript_is_flagged(tmp_path: Path) -> None:
    import subprocess

    wav = tmp_path / "fox.wav"
    subprocess.run(["espeak-ng", "-v", "en-us", "-w", str(wav), "The quick brown fox jumps over the lazy dog."],
                   check=True)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error", AlignWarning)
        right = align_recording(wav, "The quick brown fox jumps over the lazy dog.", "en")
    assert right.method.startswith("forced alignment by PocketSphinx") and "dh" in right.phones
    with pytest.warns(AlignWarning) as record:
        align_recording(wav, "Rice is often served in round bowls.", "en")
    assert any("matches the transcript poorly" in str(w.message) for w in record)


def test_no_transcript_outside_english_is_refused() -> None:
    with pytest.raises(AlignError, match="English only"):
        align_recording(WAV, None, "de")


def test_empty_transcript_is_refused() -> None:
    with pytest.raises(AlignError, match="transcript is empty"):
        align_recording(WAV, "  ", "de")


def test_transcript_from_a_words_textgrid(tmp_path: Path) -> None:
    alignment = align_recording(WAV, TEXT, "de")
    grid = tmp_path / "a.TextGrid"
    grid.write_text(textgrid_text(alignment), encoding="utf-8")
    assert read_transcript(grid) == " ".join(alignment.words)
    # the phones tier is what a label reader takes from it, and it reads back as written
    phones = read_labels(grid)
    assert phones.tier == "phones" and phones.labels == alignment.phones
    np.testing.assert_allclose(phones.ends, alignment.ends)
    assert read_labels(grid, tier="phonemes").labels == alignment.phonemes


def test_ipa_phones_map_by_their_base() -> None:
    assert ipa_phone("aɪ") == "a"  # a diphthong by where the lips start
    assert ipa_phone("iː") == "i" and ipa_phone("ɐ̃") == "ɐ" and ipa_phone("tʃʲ") == "tʃ"
    with pytest.raises(AlignError, match=r"'ǃ' has no entry in phones_ipa.tsv"):
        ipa_phone("ǃ")


def test_long_transcripts_are_cut_after_sentences() -> None:
    text = " ".join(f"Satz {k} hat hier genau sieben Wörter." for k in range(30))
    parts = split_text(text, max_words=60)
    assert " ".join(parts) == text and all(p.endswith(".") for p in parts)
    assert max(len(p.split()) for p in parts) <= 60 and len(parts) >= 4


def test_long_recording_aligned_in_parts(tmp_path: Path) -> None:
    """Four copies of the utterance, said four times in the transcript, aligned part by part: each
    copy's phones land in its own copy of the recording."""
    rec = read_recording(WAV)
    one = rec.samples
    quad = _write_wav(tmp_path / "four.wav", np.concatenate([one] * 4))
    from coartic.align.alignment import align_by_synthesis

    full = read_recording(quad)
    done: list[tuple[int, int]] = []
    import coartic.align.alignment as alignment_module

    text = " ".join([TEXT] * 4)
    parts = alignment_module.split_text
    try:
        alignment_module.split_text = lambda t: parts(t, max_words=7)  # type: ignore[assignment]
        alignment = align_by_synthesis(full, text, "de", progress=lambda k, n: done.append((k, n)))
    finally:
        alignment_module.split_text = parts  # type: ignore[assignment]
    assert done == [(1, 4), (2, 4), (3, 4), (4, 4)]
    reference = LabelMap.builtin("german_sampa").apply(read_labels(LABELS))
    d = rec.duration
    for k in range(4):
        mine = [i for i, w in enumerate(alignment.word_of) if 7 * k <= w < 7 * (k + 1)]
        assert d * k + 0.2 < alignment.starts[mine[0]] < d * k + 0.5  # "Sie" of copy k starts at 0.35 s
        seg = alignment.segments()
        copy = type(seg)(tuple(seg.labels[i] for i in mine), seg.starts[mine] - d * k, seg.ends[mine] - d * k)
        assert boundary_accuracy(reference, copy).median_ms < 60


def test_align_cli_writes_textgrid_and_report(tmp_path: Path) -> None:
    out = tmp_path / "out"
    res = CliRunner().invoke(app, ["align", str(WAV), "--text", TEXT, "--lang", "de", "--out", str(out)])
    assert res.exit_code == 0, res.output
    grid = out / "dfgspp_mo1_prosody_0020.TextGrid"
    assert read_labels(grid).tier == "phones"
    report = (out / "dfgspp_mo1_prosody_0020.align.txt").read_text()
    assert "espeak" in report and re.search(r"warp distance ratio: 0\.\d+", report)
    # a rerun on another recording's output is refused without --force
    res = CliRunner().invoke(app, ["align", str(WAV), "--text", TEXT, "--lang", "it", "--out", str(out)])
    assert res.exit_code == 2


def test_align_cli_errors_exit_nonzero(tmp_path: Path) -> None:
    res = CliRunner().invoke(app, ["align", str(LABELS), "--text", TEXT, "--lang", "de", "--out", str(tmp_path / "o")])
    assert res.exit_code == 2 and "not a readable WAV" in res.output
    res = CliRunner().invoke(app, ["align", str(WAV), "--text", TEXT, "--transcript", str(LABELS), "--out",
                                   str(tmp_path / "o")])
    assert res.exit_code == 2 and "not both" in res.output


def test_animate_a_recording_with_exports(tmp_path: Path) -> None:
    out = tmp_path / "anim"
    res = CliRunner().invoke(app, ["animate", str(WAV), "--text", TEXT, "--lang", "de", "--out", str(out),
                                   "--export", "arkit,visemes,rhubarb", "--preview", "none"])
    assert res.exit_code == 0, res.output
    stem = "dfgspp_mo1_prosody_0020"
    for suffix in (".TextGrid", ".align.txt", ".wav", ".fap", ".arkit.csv", ".visemes.csv", ".rhubarb.tsv"):
        assert (out / f"{stem}{suffix}").is_file(), suffix
    # the animation lasts as long as the recording, and the lips close for the /b/ of 'arbeitete'
    seg = read_labels(out / "segments.tsv")
    assert seg.ends[-1] == pytest.approx(read_recording(WAV).duration, abs=0.05)
    assert "b" in seg.labels


def test_animate_refuses_text_with_label_files(tmp_path: Path) -> None:
    res = CliRunner().invoke(app, ["animate", str(LABELS), "--text", TEXT, "--out", str(tmp_path / "o")])
    assert res.exit_code == 2 and "go with a recording" in res.output


def test_english_mfa_textgrid_error_points_to_the_arpabet_map(tmp_path: Path) -> None:
    phones = [("", 0.0, 0.2), ("DH", 0.2, 0.26), ("AH0", 0.26, 0.31), ("K", 0.31, 0.4), ("AE1", 0.4, 0.55),
              ("T", 0.55, 0.62), ("", 0.62, 0.9)]
    words = [("", 0.0, 0.2), ("the", 0.2, 0.31), ("cat", 0.31, 0.62), ("", 0.62, 0.9)]
    lines = ['File type = "ooTextFile"', 'Object class = "TextGrid"', "", "xmin = 0", "xmax = 0.9",
             "tiers? <exists>", "size = 2", "item []:"]
    for k, (name, items) in enumerate((("words", words), ("phones", phones)), start=1):
        lines += [f"    item [{k}]:", '        class = "IntervalTier"', f'        name = "{name}"', "        xmin = 0",
                  "        xmax = 0.9", f"        intervals: size = {len(items)}"]
        for j, (lab, s, e) in enumerate(items, start=1):
            lines += [f"        intervals [{j}]:", f"            xmin = {s}", f"            xmax = {e}",
                      f'            text = "{lab}"']
    grid = tmp_path / "mfa.TextGrid"
    grid.write_text("\n".join(lines) + "\n")
    res = CliRunner().invoke(app, ["animate", str(grid), "--out", str(tmp_path / "o"), "--preview", "none"])
    assert res.exit_code == 2
    assert "phone 'DH'" in res.output and "--label-map english_arpabet" in " ".join(res.output.split())
    res = CliRunner().invoke(app, ["animate", str(grid), "--out", str(tmp_path / "o"), "--preview", "none",
                                   "--label-map", "english_arpabet"])
    assert res.exit_code == 0, res.output


def test_lips_from_the_audio_alone(tmp_path: Path) -> None:
    """End to end on the real German EMA: a table fitted on utterance 0024 (targets, MAUS labels)
    predicts 0020's lip aperture and jaw opening from 0020's audio alone (aligned by coartic): better
    than the constant, and not far from the same table on 0020's MAUS labels (measured: LA 3.58 vs
    2.39 mm, JO 1.83 vs 2.09 mm; bench/align_accuracy.py has the full fit)."""
    from coartic.fit import load_spec
    from coartic.jobs.fit import fit_job
    from coartic.fit.data import load_utterances
    from coartic.evaluation.score import score_utterances, with_fallbacks
    from coartic.model import Utterance

    u24 = (DATA / "dfgspp_mo1_prosody_0024_ema.csv", DATA / "dfgspp_mo1_prosody_0024_Segment.tsv")
    u20 = (DATA / "dfgspp_mo1_prosody_0020_ema.csv", LABELS)
    role = 'role_map = { UL = "ul", LL = "ll", JAW = "jw", axes = { vertical = "+z", anterior = "-y" } }\n'
    specs = []
    for name, (ema, lab) in (("train", u24), ("test", u20)):
        spec = tmp_path / f"{name}.toml"
        spec.write_text(f'[corpus]\nfiles = ["{ema}"]\nlabels = ["{lab}"]\nlabel_map = "german_sampa"\n{role}'
                        '[model]\nchannels = ["LA", "JO"]\npauses = "one"\n[parameters]\nfree = ["target"]\n')
        specs.append(spec)
    table = fit_job(specs[0], tmp_path / "fit", quiet=True, report=False).table()
    train = load_utterances(load_spec(specs[0]))
    (test,) = load_utterances(load_spec(specs[1]))
    seg = align_recording(WAV, TEXT, "de").segments()
    heard = Utterance(seg.labels, seg.starts, seg.ends, test.times, test.name, test.observed, test.valid, test.meta)
    rmse: dict[str, dict[str, float]] = {}
    for what, utt in (("maus", test), ("audio", heard)):
        scored, _ = with_fallbacks([utt], table, ["LA", "JO"], LabelMap.builtin("german_sampa"))
        rows = score_utterances(table, scored, ["LA", "JO"], train=train).baseline_rows()
        rmse[what] = {f"{r['channel']} {r['model']}": r["rmse_mm"] for r in rows}
    for ch in ("LA", "JO"):
        assert rmse["audio"][f"{ch} table"] < rmse["audio"][f"{ch} constant"], rmse
        assert rmse["audio"][f"{ch} table"] < 1.6 * rmse["maus"][f"{ch} table"], rmse


def test_long_english_recording_aligned_by_pocketsphinx_in_parts(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """An English recording in parts: the parts found by alignment by synthesis, each aligned by
    PocketSphinx alone, progress part by part; the phones land where espeak-ng said them."""
    import coartic.align.alignment as alignment_module
    from coartic.align.espeak import speak
    from coartic.align.synthesis import ipa_map
    from coartic.io.labels import Segments

    text = ("Glue the sheet to the dark blue background. It's easy to tell the depth of a well. "
            "Rice is often served in round bowls.")
    said = speak(text, "en-us")
    wav = tmp_path / "three.wav"
    with wave.open(str(wav), "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(said.rate)
        w.writeframes((np.clip(said.samples, -1, 1) * 32767).astype("<i2").tobytes())
    pm = ipa_map()
    reference = Segments(tuple(pm.phonemes[ipa_phone(p)] if p else "#" for p in said.phones),
                         said.starts / said.rate, said.ends / said.rate)
    split = alignment_module.split_text
    monkeypatch.setattr(alignment_module, "split_text", lambda t: split(t, max_words=9))
    done: list[tuple[int, int]] = []
    alignment = align_recording(wav, text, "en", progress=lambda k, n: done.append((k, n)))
    assert alignment.method.endswith("in 3 parts") and done[-1] == (3, 3)
    assert len(alignment.words) == 24
    acc = boundary_accuracy(reference, alignment.segments())
    assert acc.median_ms < 25 and acc.within(40) > 0.8, acc.summary()


def test_animate_a_float_stereo_recording(tmp_path: Path) -> None:
    """A 32-bit float stereo WAV at 44.1 kHz (what audio editors export): aligned as mono 16 kHz,
    and its sound written as 16-bit PCM beside the animation (the runtime's WAV copy takes PCM only)."""
    from scipy.io import wavfile
    from scipy.signal import resample_poly

    rate, data = wavfile.read(WAV)
    mono = resample_poly(data.astype(np.float32) / 32768, 147, 80).astype(np.float32)  # 24 kHz -> 44.1 kHz
    src = tmp_path / "float.wav"
    wavfile.write(src, 44100, np.stack([mono, 0.5 * mono], axis=1))
    out = tmp_path / "anim"
    res = CliRunner().invoke(app, ["animate", str(src), "--text", TEXT, "--lang", "de", "--out", str(out),
                                   "--preview", "none"])
    assert res.exit_code == 0, res.output
    with wave.open(str(out / "float.wav"), "rb") as w:
        assert (w.getsampwidth(), w.getnchannels(), w.getframerate()) == (2, 2, 44100)
        assert w.getnframes() == len(mono)
    res = CliRunner().invoke(app, ["animate", str(tmp_path / "none.wav"), "--text", TEXT, "--out", str(tmp_path / "o")])
    assert res.exit_code == 2 and "none.wav: no such file" in res.output
