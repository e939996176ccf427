"""APML-like emotion markup (issue 27): the words to say with the emotions around them, parsed
with the standard library's XML parser, errors naming line and column, timed by Festival's words
into the spans `--emotion-spans` gives."""

from __future__ import annotations

import csv
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from typer.testing import CliRunner

from coartic.cli import app
from coartic.console import EXIT_ERROR
from coartic.emotions import EmotionError, EmotionSpan
from coartic.runtime.markup import apply_to_utterance, parse_markup, spans_from_words, with_markup
from test_emotions_runtime import TRUTH

MARKUP = """<apml>
  <performative affect="joy" intensity="0.6">Papà mamma</performative> tutti
  <performative type="inform" affect="anger">tuffati</performative> bimbi.
</apml>
"""


def test_markup_gives_each_word_its_emotion() -> None:
    m = parse_markup("""<apml><performative type="inform">Il <performative affect="joy" intensity="0.5">babbo
      mang</performative>ia</performative> la <performative affect="sadness">pappa.</performative></apml>""", "m.xml")
    assert [(w.word, w.emotion, w.intensity) for w in m.words] == [
        ("Il", None, 1.0), ("babbo", "joy", 0.5), ("mangia", "joy", 0.5),  # a word split by a tag: its first letter's
        ("la", None, 1.0), ("pappa.", "sadness", 1.0)]
    assert m.text == "Il babbo mangia la pappa." and m.emotions() == ("joy", "sadness")


@pytest.mark.parametrize("text, message", [
    ('<apml>\n <performative affect="joy">a</performativ>\n</apml>', r"m\.xml, line 2, column 32: not well-formed markup: mismatched tag"),
    ('<apml>\n  <emph>a</emph></apml>', r"m\.xml, line 2, column 3: <emph>: not an element of the emotion markup"),
    ('<apml><performative affect="joy" intensity="2">a</performative></apml>', r"line 1, column 7: intensity='2'"),
    ('<apml><performative mood="joy">a</performative></apml>', r"line 1, column 7: .* unknown attribute\(s\) mood"),
    ('<apml><performative intensity="0.5">a</performative></apml>', r"has an intensity but no affect"),
    ("Il babbo", r"line 1, column 1: not well-formed markup: syntax error \(the markup is XML"),
    ("<apml> </apml>", r"m\.xml: the markup has no words to say"),
])
def test_bad_markup_is_named_by_line_and_column(text: str, message: str) -> None:
    with pytest.raises(EmotionError, match=message):
        parse_markup(text, "m.xml")


def test_an_emotion_the_table_lacks_is_named_where_it_is_written() -> None:
    m = parse_markup('<apml>papà\n  <performative affect="pride">mamma</performative></apml>', "m.xml")
    with pytest.raises(EmotionError, match=r"m\.xml, line 2, column 3: affect='pride': the table knows neutral, joy"):
        with_markup(TRUTH, m)


def test_words_are_timed_by_the_spoken_ones_numbers_read_out_included() -> None:
    m = parse_markup('<a><performative affect="joy">Ho 25</performative> anni, <performative affect="fear">'
                     'davvero</performative> sì</a>', "m.xml")
    said = [("ho", 0.1, 0.2), ("venti", 0.2, 0.5), ("cinque", 0.5, 0.8), ("anni", 0.8, 1.1), ("davvero", 1.2, 1.6),
            ("sì", 1.6, 1.9)]
    assert spans_from_words(m, said) == [EmotionSpan(0.1, 0.8, "joy", 1.0), EmotionSpan(1.2, 1.6, "fear", 1.0)]
    # as the pipeline gives them: Festival's word per phone, its number, the phones' times
    utt = SimpleNamespace(words=("", "ho", "ho", "venti", "cinque", "anni", "davvero", "davvero", "sì", ""),
                          word_ids=(-1, 3, 3, 4, 5, 6, 7, 7, 8, -1),
                          starts=np.array([0.0, 0.1, 0.15, 0.2, 0.5, 0.8, 1.2, 1.4, 1.6, 1.9]),
                          ends=np.array([0.1, 0.15, 0.2, 0.5, 0.8, 1.1, 1.4, 1.6, 1.9, 2.2]))
    t = apply_to_utterance(with_markup(TRUTH, m), utt)
    assert t.metadata["expression"] == {"spans": [[0.1, 0.8, "joy", 1.0], [1.2, 1.6, "fear", 1.0]]}
    assert apply_to_utterance(TRUTH, utt) is TRUTH  # no markup: the table as it is


@pytest.mark.festival
def test_speak_with_markup_moves_the_lips_in_the_marked_words_only(tmp_path: Path) -> None:
    table = tmp_path / "emotive.json"
    TRUTH.save(table)
    markup = tmp_path / "m.xml"
    markup.write_text(MARKUP, encoding="utf-8")
    runner = CliRunner()
    res = runner.invoke(app, ["speak", "--emotion-markup", str(markup), "--table", str(table), "--out",
                              str(tmp_path / "m"), "--preview", "none"])
    assert res.exit_code == 0, res.output
    res = runner.invoke(app, ["speak", "Papà mamma tutti tuffati bimbi.", "--table", str(table), "--out",
                              str(tmp_path / "n"), "--preview", "none"])
    assert res.exit_code == 0, res.output
    a, b = (np.genfromtxt(tmp_path / d / "channels.csv", delimiter=",", names=True) for d in ("m", "n"))
    with (tmp_path / "m" / "segments.tsv").open(encoding="utf-8") as f:
        rows = list(csv.DictReader(f, delimiter="\t"))
    seg = {k: np.array([float(r[k]) for r in rows]) for k in ("start", "end")}
    d = a["LR"] - b["LR"]
    t = a["time"]

    def inside(first: int, last: int) -> np.ndarray:  # frames 0.1 s (the ramp's half) inside the segments
        return (t >= seg["start"][first] + 0.1) & (t <= seg["end"][last] - 0.1)

    # segments: # p a p a m a m m a | t u t t i | t u f f a t i | b i m b i # #
    np.testing.assert_allclose(d[inside(1, 9)], 0.6 * 4.0, atol=1e-9)  # joy at 0.6 on "Papà mamma"
    np.testing.assert_allclose(d[inside(15, 21)], -1.5, atol=1e-9)  # anger on "tuffati"
    np.testing.assert_allclose(d[inside(11, 13)], 0.0, atol=1e-9)  # "tutti": neutral
    np.testing.assert_allclose(d[t >= seg["start"][22] + 0.1], 0.0, atol=1e-9)  # "bimbi." and after
    bad = runner.invoke(app, ["speak", "papà", "--emotion-markup", str(markup), "--table", str(table), "--out",
                              str(tmp_path / "x")])
    assert bad.exit_code == EXIT_ERROR and "give one (the markup holds the words to say)" in bad.output
    bad = runner.invoke(app, ["speak", "--emotion-markup", str(markup), "--emotion", "joy", "--table", str(table),
                              "--out", str(tmp_path / "x")])
    assert bad.exit_code == EXIT_ERROR and "--emotion and --emotion-markup: give one" in bad.output
