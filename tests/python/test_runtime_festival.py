"""Festival's Italian voice and its phone map (coartic.runtime.festival), with the real Festival."""

from __future__ import annotations

import re
import stat
from pathlib import Path

import numpy as np
import pytest

from coartic.io.labelmap import MODEL_PHONEMES
from coartic.runtime.errors import FestivalError, PhoneMapError
from coartic.runtime.festival import PhoneMap, prepare_text, synthesize, wav_duration

PHONESET = Path("/usr/share/festival/italian_scm/italian_phoneset.scm")
SENTENCE = "Il babbo mangia la pappa, poi va via."


def festival_phones() -> list[str]:
    """The phone names declared in Festival's Italian defPhoneSet."""
    text = PHONESET.read_text(encoding="latin-1")
    body = text[text.index("(;;  VOCALI"):]
    return re.findall(r"^\s*\(?\(\s*([A-Za-z#][A-Za-z0-9]*)\s+[+-]\s", body, flags=re.M)


@pytest.mark.festival
def test_every_festival_italian_phone_is_mapped_to_model_phonemes() -> None:
    phones = festival_phones()
    assert len(phones) >= 40 and {"a1", "dZ", "nf", "ng", "#"} <= set(phones)
    pmap = PhoneMap.load()
    assert sorted(pmap.phonemes) == sorted(phones)
    for phone in phones:
        assert pmap.phonemes[phone] in MODEL_PHONEMES, phone
    for phoneme, fallbacks in pmap.fallbacks.items():
        assert all(f in MODEL_PHONEMES and f != phoneme for f in fallbacks), phoneme


def test_phone_map_decisions() -> None:
    pmap = PhoneMap.load()
    assert pmap.to_phonemes(["#", "a1", "O1", "p", "nf", "ng", "Z"]) == ["#", "a", "O", "p", "f", "n", "S"]
    assert pmap.fallbacks["o"] == ("O", "u")
    with pytest.raises(PhoneMapError, match=r"Festival phone 'xx' \(segment 2\) is not in phones_italian.tsv"):
        pmap.to_phonemes(["a", "xx"])


def test_malformed_phone_map_names_the_line(tmp_path: Path) -> None:
    bad = tmp_path / "map.tsv"
    bad.write_text("festival\tphoneme\tfallbacks\twhy\na\ta\t\t\nb\t\t\t\n")
    with pytest.raises(PhoneMapError, match=r"map.tsv, line 3"):
        PhoneMap.load(bad)
    bad.write_text("festival\tphoneme\tfallbacks\na\ta\t\na\te\t\n")
    with pytest.raises(PhoneMapError, match=r"line 3: Festival phone 'a' is mapped twice"):
        PhoneMap.load(bad)
    bad.write_text("festival\tphoneme\tfallbacks\no\to\tu\no1\to\ta\n")
    with pytest.raises(PhoneMapError, match=r"line 3: fallbacks a for phoneme 'o' differ from the u"):
        PhoneMap.load(bad)
    bad.write_text("phone\tphoneme\n")
    with pytest.raises(PhoneMapError, match="line 1: header"):
        PhoneMap.load(bad)


def test_text_preparation() -> None:
    assert prepare_text("  l\u2019altro   giorno\n") == "l'altro giorno"
    assert prepare_text("perché città") == "perché città"
    with pytest.raises(FestivalError, match="empty text"):
        prepare_text(" \n\t ")
    with pytest.raises(FestivalError, match=r"U\+1F600\) at position 5"):
        prepare_text("ciao \U0001F600")


@pytest.mark.festival
def test_synthesis_segments_tile_the_wav(tmp_path: Path) -> None:
    utt = synthesize(SENTENCE, tmp_path / "s.wav")
    assert utt.phones[0] == "#" and utt.phones[-1] == "#"
    assert "p" in utt.phones and "v" in utt.phones
    assert utt.starts[0] == 0.0
    np.testing.assert_array_equal(utt.starts[1:], utt.ends[:-1])
    assert np.all(utt.ends > utt.starts)
    assert utt.duration == wav_duration(tmp_path / "s.wav")
    # Festival's WAV ends within a few tens of ms after its last segment
    assert 0.0 <= utt.duration - utt.ends[-1] < 0.05


@pytest.mark.festival
def test_duration_stretch_speeds_speech_up(tmp_path: Path) -> None:
    normal = synthesize(SENTENCE, tmp_path / "n.wav")
    fast = synthesize(SENTENCE, tmp_path / "f.wav", stretch=0.6)
    assert fast.phones == normal.phones
    ratio = (fast.ends[-1] - fast.ends[0]) / (normal.ends[-1] - normal.ends[0])
    assert 0.5 < ratio < 0.7


@pytest.mark.festival
def test_quotes_and_accents_reach_festival(tmp_path: Path) -> None:
    utt = synthesize('Disse "sì" \\ perché', tmp_path / "q.wav")
    assert "i1" in utt.phones and "e1" in utt.phones  # sì, perché: the accents were read


def test_festival_not_on_path(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PATH", str(tmp_path))
    with pytest.raises(FestivalError, match="'festival' not found on PATH"):
        synthesize("ciao", tmp_path / "x.wav")


def test_festival_failure_is_reported(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    fake = tmp_path / "festival"
    fake.write_text("#!/bin/sh\necho 'SIOD ERROR: something broke' >&2\nexit 3\n")
    fake.chmod(fake.stat().st_mode | stat.S_IEXEC)
    monkeypatch.setenv("PATH", str(tmp_path))
    with pytest.raises(FestivalError, match=r"exit code 3.*SIOD ERROR: something broke"):
        synthesize("ciao", tmp_path / "x.wav")


@pytest.mark.festival
def test_unknown_voice_is_named(tmp_path: Path) -> None:
    with pytest.raises(FestivalError, match="voice 'xx_diphone'"):
        synthesize("ciao", tmp_path / "x.wav", voice="xx_diphone")


def test_bad_rate_and_voice_name(tmp_path: Path) -> None:
    with pytest.raises(FestivalError, match="stretch"):
        synthesize("ciao", tmp_path / "x.wav", stretch=0.0)
    with pytest.raises(FestivalError, match="voice name"):
        synthesize("ciao", tmp_path / "x.wav", voice="pc)(quit")


FAKE_FESTIVAL = '''#!{python}
# Stands in for Festival: finds the output paths in the script it is given, writes the segments
# below and a silent 16 kHz WAV as long as the last segment.
import re, sys, wave
script = open(sys.argv[-1], encoding="latin-1").read()
segs = re.search(r'fopen "([^"]+)"', script).group(1)
wav = re.search(r'utt.save.wave utt "([^"]+)"', script).group(1)
rows = {rows!r}
open(segs, "w").write("".join(f"{{p}}\\t{{e:f}}\\n" for p, e in rows))
with wave.open(wav, "wb") as w:
    w.setnchannels(1); w.setsampwidth(2); w.setframerate(16000)
    w.writeframes(b"\\0\\0" * int(16000 * rows[-1][1]))
'''


def fake_festival(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, rows: list[tuple[str, float]]) -> None:
    import sys

    fake = tmp_path / "bin" / "festival"
    fake.parent.mkdir()
    fake.write_text(FAKE_FESTIVAL.format(python=sys.executable, rows=rows))
    fake.chmod(fake.stat().st_mode | stat.S_IEXEC)
    monkeypatch.setenv("PATH", str(fake.parent))


def test_zero_length_segments_are_dropped_and_named(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    fake_festival(tmp_path, monkeypatch, [("#", 0.2), ("p", 0.2), ("a1", 0.35), ("#", 0.5)])
    utt = synthesize("pa", tmp_path / "x.wav")
    assert utt.phones == ("#", "a1", "#") and utt.dropped == ("p",)
    np.testing.assert_allclose(utt.starts, [0.0, 0.2, 0.35])
    assert utt.duration == pytest.approx(0.5)


def test_unknown_festival_phone_is_named_by_speak(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from coartic.runtime.pipeline import speak_text
    from coartic.table import ParameterTable

    fake_festival(tmp_path, monkeypatch, [("#", 0.2), ("a1", 0.3), ("QQ", 0.4), ("#", 0.5)])
    table = ParameterTable.load(Path(__file__).resolve().parents[2] / "corpus-synthetic" / "ground_truth.json")
    with pytest.raises(PhoneMapError, match=r"Festival phone 'QQ' \(segment 3\) is not in phones_italian.tsv"):
        speak_text("qq", table, tmp_path / "o", preview="none")


def test_festival_gets_a_heap_sized_to_the_text(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # the default heap (10 million cells) costs 0.2 s of page faults at every start; a text gets
    # FESTIVAL_HEAP_CELLS and more as it grows (FESTIVAL_HEAP_CELLS_PER_CHAR)
    from coartic.runtime.festival import FESTIVAL_HEAP_CELLS, FESTIVAL_HEAP_CELLS_PER_CHAR

    fake_festival(tmp_path, monkeypatch, [("#", 0.2), ("a1", 0.35), ("#", 0.5)])
    log = tmp_path / "argv.txt"
    fake = tmp_path / "bin" / "festival"
    fake.write_text(fake.read_text().replace("import re, sys, wave\n",
                                             f"import re, sys, wave\nopen({str(log)!r}, 'a').write(' '.join(sys.argv[1:3]) + '\\n')\n"))
    synthesize("pa", tmp_path / "x.wav")
    synthesize("pa " * 1000, tmp_path / "y.wav")
    short, long = log.read_text().splitlines()
    assert short == f"--heap {FESTIVAL_HEAP_CELLS + 2 * FESTIVAL_HEAP_CELLS_PER_CHAR}"
    assert long == f"--heap {FESTIVAL_HEAP_CELLS + len(prepare_text('pa ' * 1000)) * FESTIVAL_HEAP_CELLS_PER_CHAR}"


def test_a_heap_too_small_is_named(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    fake = tmp_path / "festival"
    fake.write_text("#!/bin/sh\necho 'SIOD ERROR: ran out of storage ' >&2\nexit 255\n")
    fake.chmod(fake.stat().st_mode | stat.S_IEXEC)
    monkeypatch.setenv("PATH", str(tmp_path))
    with pytest.raises(FestivalError, match=r"ran out of storage.*Festival's heap of 1000400 cells was too small"):
        synthesize("ciao", tmp_path / "x.wav")


def test_festival_runs_while_the_caller_goes_on_and_stops_with_it(tmp_path: Path,
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    import os
    import shutil
    import time

    from coartic.runtime.festival import start_synthesis

    fake = tmp_path / "festival"
    pidfile = tmp_path / "pid"
    # the pid written whole then renamed: the file must never be seen empty (a redirection creates
    # it before echo writes)
    fake.write_text(f"#!/bin/sh\necho $$ > {pidfile}.tmp && {shutil.which('mv')} {pidfile}.tmp {pidfile}\n"
                    f"exec {shutil.which('sleep')} 60\n")
    fake.chmod(fake.stat().st_mode | stat.S_IEXEC)
    monkeypatch.setenv("PATH", str(tmp_path))
    with start_synthesis("ciao") as run:
        for _ in range(12_000):  # a guard against hanging, not a timing check: Festival started at once
            if pidfile.exists():
                break
            time.sleep(0.01)
        else:
            pytest.fail("the fake festival never started")
        pid = pidfile.read_text().strip()
        os.kill(int(pid), 0)  # returned while Festival still runs (it sleeps until stopped)
    # leaving the block (here without taking the result: an error elsewhere) stopped it
    with pytest.raises(ProcessLookupError):
        os.kill(int(pid), 0)
    with pytest.raises(FestivalError, match="closed before its result"):
        run.result(tmp_path / "x.wav")


def test_speak_refuses_a_synthesis_of_another_text(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from coartic.runtime.errors import AnimationError
    from coartic.runtime.festival import start_synthesis
    from coartic.runtime.pipeline import speak_text
    from coartic.table import ParameterTable

    fake_festival(tmp_path, monkeypatch, [("#", 0.2), ("a1", 0.35), ("#", 0.5)])
    table = ParameterTable.load(Path(__file__).resolve().parents[2] / "corpus-synthetic" / "ground_truth.json")
    with start_synthesis("pa") as run, pytest.raises(AnimationError, match="Festival was started on 'pa', not on 'ma'"):
        speak_text("ma", table, tmp_path / "o", preview="none", synthesis=run)
    with start_synthesis(" pa ") as run:  # the same text as Festival reads it
        assert speak_text("pa", table, tmp_path / "o", preview="none", synthesis=run).utterance is not None
