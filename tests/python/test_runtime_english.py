"""`coartic speak --lang en`: Festival's English voice (kal_diphone, radio/ARPAbet phones) and its
phone map onto the model's Italian phonemes (phones_english.tsv), with fallbacks by phonetic class."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from coartic.cli import app
from coartic.io.labels import Segments
from coartic.io.labelmap import MODEL_PHONEMES, resolve_label_map
from coartic.runtime.animate import NEXT_PHONEME, substitute
from coartic.runtime.errors import FestivalError
from coartic.runtime.festival import PhoneMap, synthesize
from coartic.runtime.pipeline import speak_text
from coartic.runtime.shipped import load_shipped_table
from coartic.table import CHANNELS

PHONESET = Path("/usr/share/festival/radio_phones.scm")
PARAGRAPH = ("Hello, who is happy here? The thing is, I just measured your azure ring, Joy. "
             "Oh, how nice the church bells sound; yes, we were there, ahead of the others.")


def radio_phones() -> list[str]:
    """The phones of Festival's radio phone set (the English voices' ARPAbet), from its defPhoneSet."""
    text = PHONESET.read_text(encoding="latin-1")
    return re.findall(r"^\s*\(([a-z#]+)\s+[+-](?:\s+\S+){7}\s*\)", text, flags=re.M)


@pytest.mark.festival
def test_every_festival_english_phone_is_mapped() -> None:
    phones = radio_phones()
    assert len(phones) == 50 and {"hh", "hv", "zh", "pau", "axr"} <= set(phones)
    pmap = PhoneMap.load(lang="en")
    assert sorted(pmap.phonemes) == sorted(phones)


def test_english_map_agrees_with_the_english_label_map() -> None:
    """One mapping of English: where the corpus label map english_arpabet knows a phone, the phone
    map gives the same phoneme (Festival writes ARPAbet in lower case, without stress digits)."""
    pmap = PhoneMap.load(lang="en")
    lmap = resolve_label_map("english_arpabet")
    assert lmap is not None
    compared = 0
    for phone, phoneme in pmap.phonemes.items():
        if phone in ("axr", "el", "em", "en", "hv", "nx", "brth", "h#"):  # radio-only phones
            continue
        label = "AH0" if phone == "ax" else phone  # schwa: ARPAbet spells it AH0
        assert lmap.map_label(label) == phoneme, phone
        compared += 1
    assert compared == 42


def test_every_english_sound_reaches_a_phoneme_of_the_italian_table() -> None:
    """Every phone ends on a phoneme of the shipped Italian table, through its fallbacks by class;
    /h/ (no oral posture of its own) shows the phoneme after it."""
    pmap = PhoneMap.load(lang="en")
    table = load_shipped_table()
    have = set(table.phonemes)
    for phone, phoneme in pmap.phonemes.items():
        chain = (phoneme, *pmap.fallbacks.get(phoneme, ()))
        assert any(p in have or p == NEXT_PHONEME for p in chain), phone
        assert all(p in MODEL_PHONEMES or p in ("h", NEXT_PHONEME) for p in chain), phone
    needing = {ph for ph in pmap.phonemes.values() if ph not in have}
    assert needing == {"h"}  # the Italian table has the glides /j w/ too
    assert pmap.fallbacks["h"] == (NEXT_PHONEME,) and pmap.fallbacks["j"] == ("i",) and pmap.fallbacks["w"] == ("u",)


def test_h_shows_the_phoneme_after_it_or_before_a_pause() -> None:
    table = load_shipped_table()
    fallbacks = PhoneMap.load(lang="en").fallbacks
    labels = ("#", "h", "u", "h", "h", "a", "p", "h", "#", "h", "#")
    seg = Segments(labels, np.arange(len(labels), dtype=float), np.arange(1, len(labels) + 1, dtype=float))
    out, used = substitute(seg, table, CHANNELS, fallbacks)
    assert out.labels == ("#", "u", "u", "a", "a", "a", "p", "p", "#", "#", "#")
    assert used == {"h": NEXT_PHONEME}


def test_unknown_language_is_refused(tmp_path: Path) -> None:
    with pytest.raises(FestivalError, match=r"language 'fr' .* \(known: it, en\)"):
        synthesize("bonjour", tmp_path / "x.wav", lang="fr")
    res = CliRunner().invoke(app, ["speak", "bonjour", "--lang", "fr", "-o", str(tmp_path / "o")])
    assert res.exit_code == 2 and "--lang 'fr'" in res.output and "Traceback" not in res.output
    assert not (tmp_path / "o").exists()


@pytest.mark.festival
def test_english_paragraph_with_the_shipped_table(tmp_path: Path) -> None:
    table = load_shipped_table()
    result = speak_text(PARAGRAPH, table, tmp_path / "o", preview="none", lang="en")
    utt = result.utterance
    assert utt is not None and {"hh", "zh", "jh", "y", "w", "th", "dh", "ng"} <= set(utt.phones)
    a = result.animation
    # only /h/, which the Italian table has no phoneme for, is replaced: by the phoneme after it
    assert a.substitutions == {"h": NEXT_PHONEME}
    shown = dict(zip(range(len(a.segments.labels)), a.segments.labels))
    for i, phone in enumerate(utt.phones):
        if phone == "hh" and i + 1 < len(utt.phones):
            after = PhoneMap.load(lang="en").phonemes[utt.phones[i + 1]]
            if after in table.phonemes and after != "#":
                assert shown[i] == after, (i, utt.phones[i - 1:i + 2])
    # the bilabials of "happy", "measured", "bells" close the lips (k_R ~ 1 in the fitted table):
    # inner-lip aperture ULO + LLO + 1 mm (the session's rest gap) below 0 within each of them
    closed = [i for i, p in enumerate(utt.phones) if p in ("p", "b", "m")]
    assert len(closed) == 3
    aperture = a.channels["ULO"] + a.channels["LLO"] + 1.0
    for i in closed:
        inside = (a.times >= a.segments.starts[i]) & (a.times <= a.segments.ends[i])
        assert inside.any() and aperture[inside].min() < 0.0, utt.phones[i]
    assert np.isfinite(a.channels["LLO"]).all() and a.duration == pytest.approx(utt.duration, abs=0.04)


@pytest.mark.festival
def test_cli_speak_english_without_a_table(tmp_path: Path) -> None:
    res = CliRunner().invoke(app, ["speak", "Who is happy?", "--lang", "en", "-o", str(tmp_path / "o"),
                                   "--preview", "none"])
    assert res.exit_code == 0, res.output
    out = " ".join(res.output.split())
    assert "italian_table.json (shipped with coartic" in out
    assert "the table has no /h/ (shown as the phoneme after it)" in out and "phones_english.tsv" in out
    assert (tmp_path / "o" / "Who_is_happy.wav").is_file()
    rows = (tmp_path / "o" / "segments.tsv").read_text().splitlines()
    assert any(r.split("\t")[2:4] == ["h", "u"] and r.split("\t")[4] == "hh" for r in rows), rows
