"""Label readers (TextGrid long/short, HTK and xlabel .lab, TSV) and label maps."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from coartic.io import DataError, LabelMap, Segments, read_labels
from coartic.io.labelmap import resolve_label_map
from coartic.io.labels import write_tsv
from format_fixtures import write_textgrid

LONG_TG = '''File type = "ooTextFile"
Object class = "TextGrid"

xmin = 0
xmax = 1.2
tiers? <exists>
size = 2
item []:
    item [1]:
        class = "TextTier"
        name = "events"
        xmin = 0
        xmax = 1.2
        points: size = 1
        points [1]:
            number = 0.5
            mark = "click"
    item [2]:
        class = "IntervalTier"
        name = "phones"
        xmin = 0
        xmax = 1.2
        intervals: size = 5
        intervals [1]:
            xmin = 0
            xmax = 0.3
            text = ""
        intervals [2]:
            xmin = 0.3
            xmax = 0.45
            text = "a"
        intervals [3]:
            xmin = 0.45
            xmax = 0.55
            text = "p"
        intervals [4]:
            xmin = 0.55
            xmax = 0.7
            text = "a"
        intervals [5]:
            xmin = 0.7
            xmax = 1.2
            text = "sil"
'''

SHORT_TG = '''File type = "ooTextFile"
Object class = "TextGrid"

0
1.2
<exists>
1
"IntervalTier"
"phones"
0
1.2
5
0
0.3
""
0.3
0.45
"a"
0.45
0.55
"p"
0.55
0.7
"a"
0.7
1.2
"say ""sil"""
'''


def _write(tmp_path: Path, name: str, text: str, encoding: str = "utf-8") -> Path:
    p = tmp_path / name
    p.write_text(text, encoding=encoding)
    return p


def test_textgrid_long_format_picks_first_interval_tier(tmp_path: Path) -> None:
    s = read_labels(_write(tmp_path, "a.TextGrid", LONG_TG))
    assert s.tier == "phones"
    assert s.labels == ("", "a", "p", "a", "sil")
    np.testing.assert_array_equal(s.starts, [0, 0.3, 0.45, 0.55, 0.7])
    np.testing.assert_array_equal(s.ends, [0.3, 0.45, 0.55, 0.7, 1.2])
    # the line of each interval's xmin is kept for error messages
    assert s.lines[2] == LONG_TG.splitlines().index("            xmin = 0.45") + 1


def test_textgrid_short_format_and_quote_escape(tmp_path: Path) -> None:
    s = read_labels(_write(tmp_path, "a.TextGrid", SHORT_TG))
    assert s.labels == ("", "a", "p", "a", 'say "sil"')
    np.testing.assert_array_equal(s.ends, [0.3, 0.45, 0.55, 0.7, 1.2])


def test_textgrid_utf16_as_praat_writes_it(tmp_path: Path) -> None:
    p = tmp_path / "u.TextGrid"
    p.write_bytes(LONG_TG.replace('"p"', '"ʃ"').encode("utf-16"))
    assert read_labels(p).labels[2] == "ʃ"


def test_textgrid_tier_by_name_and_errors(tmp_path: Path) -> None:
    p = _write(tmp_path, "a.TextGrid", LONG_TG)
    assert read_labels(p, tier="phones").labels[1] == "a"
    with pytest.raises(DataError, match=r"no interval tier named 'words'.*\['events', 'phones'\]"):
        read_labels(p, tier="words")
    with pytest.raises(DataError, match="point tier"):
        read_labels(p, tier="events")


def test_textgrid_truncated_names_line(tmp_path: Path) -> None:
    text = "\n".join(LONG_TG.splitlines()[:30])
    with pytest.raises(DataError, match=r"a\.TextGrid, line \d+: the TextGrid ends early"):
        read_labels(_write(tmp_path, "a.TextGrid", text))


def test_textgrid_overlap_names_label_and_line(tmp_path: Path) -> None:
    text = LONG_TG.replace("            xmin = 0.45\n", "            xmin = 0.40\n")
    line = text.splitlines().index("            xmin = 0.40") + 1
    with pytest.raises(DataError, match=rf"line {line}: label 'p' \(segment 3\).*overlaps") as e:
        read_labels(_write(tmp_path, "a.TextGrid", text))
    assert e.value.item == "p" and e.value.line == line


def test_htk_lab(tmp_path: Path) -> None:
    p = _write(tmp_path, "a.lab", "0 3000000 sil\n3000000 4500000 a\n4500000 5500000 p -12.5\n")
    s = read_labels(p)
    assert s.labels == ("sil", "a", "p")
    np.testing.assert_allclose(s.starts, [0, 0.3, 0.45])
    np.testing.assert_allclose(s.ends, [0.3, 0.45, 0.55])


def test_htk_lab_seconds_is_an_error(tmp_path: Path) -> None:
    with pytest.raises(DataError, match=r"a\.lab, line 2: line 1 has HTK times \(integers, 100 ns units\) "
                                        r"and line 2 times in seconds: HTK times must be integers"):
        read_labels(_write(tmp_path, "a.lab", "0 3000000 sil\n0.3 0.45 a\n"))


def test_festival_xlabel(tmp_path: Path) -> None:
    text = "separator ;\nnfields 1\n#\n0.300 125 pau\n0.450 125 a\n0.550 125 p\n"
    s = read_labels(_write(tmp_path, "f.lab", text))
    assert s.labels == ("pau", "a", "p")
    np.testing.assert_allclose(s.starts, [0, 0.3, 0.45])
    assert s.lines == (4, 5, 6)
    # EMU's xlabel files open with `0 125 H#`: the utterance's start, not a segment of no length
    emu = read_labels(_write(tmp_path, "u.MAU", "signal u\nnfields 1\n#\n\t0.000000\t125\tH#\n"
                                               "\t0.879940\t125\t<p:>\n\t0.939940\t125\tm\n"))
    assert emu.labels == ("<p:>", "m") and emu.lines == (5, 6)
    np.testing.assert_allclose(emu.starts, [0.0, 0.87994])
    # a zero-length segment anywhere else is still an error
    with pytest.raises(DataError, match=r"z\.lab, line 3: label 'a' \(segment 2\) ends at 0\.3 s, "
                                        r"not after its start 0\.3 s"):
        read_labels(_write(tmp_path, "z.lab", "#\n0.3 125 pau\n0.3 125 a\n"))


def test_tsv_with_header_and_unsorted(tmp_path: Path) -> None:
    s = read_labels(_write(tmp_path, "a.tsv", "start\tend\tlabel\n0\t0.3\t&p:\n0.3\t0.5\tb\n"))
    assert s.labels == ("&p:", "b") and s.lines == (2, 3)
    bad = _write(tmp_path, "b.tsv", "0.3\t0.5\tb\n0\t0.3\ta\n")
    with pytest.raises(DataError, match=r"b\.tsv, line 2: label 'a'.*out of order"):
        read_labels(bad)
    zero = _write(tmp_path, "c.tsv", "0\t0.3\ta\n0.3\t0.3\tb\n")
    with pytest.raises(DataError, match=r"line 2: label 'b'.*not after its start"):
        read_labels(zero)


def test_tsv_round_trip(tmp_path: Path) -> None:
    s = Segments(("#", "a", "p"), np.array([0.0, 0.1 + 0.2, 0.51]), np.array([0.1 + 0.2, 0.51,
                                                                              0.6]))
    write_tsv(s, tmp_path / "x.tsv")
    back = read_labels(tmp_path / "x.tsv")
    assert back.labels == s.labels
    assert np.array_equal(back.starts, s.starts) and np.array_equal(back.ends, s.ends)


def test_real_emu_segments_read() -> None:
    p = Path(__file__).parents[1] / "data/realdata/emu-ema-german/derived/dfgspp_mo1_prosody_0024_Segment.tsv"
    s = read_labels(p)
    assert len(s) == 38 and s.labels[0] == "&p:" and s.labels[1] == "m"
    assert s.ends[-1] == pytest.approx(3.99)


# --- label maps ---------------------------------------------------------------------------------


def test_german_map_and_pauses() -> None:
    m = LabelMap.builtin("german_sampa")
    assert [m.map_label(x) for x in ("&p:", "aI", "6", "b", "N", "h", "")] == [
        "#", "a", "a", "b", "n", "h", "#"]
    # MAUS also writes unstressed tense vowels without the length mark, and aspiration apart
    assert [m.map_label(x) for x in ("e", "o", "i", "u", "y", "2", "kh", "ph", "th")] == [
        "e", "o", "i", "u", "u", "o", "k", "p", "t"]


def test_unmapped_label_names_label_file_and_line(tmp_path: Path) -> None:
    p = _write(tmp_path, "a.tsv", "0\t0.3\t&p:\n0.3\t0.5\tX\n")
    s = read_labels(p)
    with pytest.raises(DataError, match=r"a\.tsv, line 2: phone 'X' \(segment 2\) has no mapping "
                                        r"in builtin map 'model'"):
        LabelMap.model().apply(s)


def test_map_files_tsv_json_keep(tmp_path: Path) -> None:
    tsv = _write(tmp_path, "m.tsv", "# comment\naa\ta\tlong a\nQ\t=\n")
    m = resolve_label_map(tsv)
    assert m.map_label("aa") == "a" and m.map_label("Q") == "Q" and m.map_label("zz") is None
    js = _write(tmp_path, "m.json", json.dumps({"aa": "a", "*": "="}))
    m2 = resolve_label_map(js)
    assert m2.map_label("zz") == "zz" and m2.map_label("sil") == "#"
    dup = _write(tmp_path, "d.tsv", "aa\ta\naa\to\n")
    with pytest.raises(DataError, match=r"d\.tsv, line 2: label 'aa' is mapped twice"):
        resolve_label_map(dup)
    with pytest.raises(DataError, match="neither a file nor a built-in map"):
        resolve_label_map("no_such_map")
    assert resolve_label_map({"x": "p"}).map_label("x") == "p"


def test_german_map_covers_both_real_utterances() -> None:
    d = Path(__file__).parents[1] / "data/realdata/emu-ema-german/derived"
    m = LabelMap.builtin("german_sampa")
    for p in sorted(d.glob("*_Segment.tsv")):
        mapped = m.apply(read_labels(p))
        assert set(mapped.labels) <= set(LabelMap.model().mapping) | {"h", "Q"}


def test_english_arpabet_map_strips_stress_and_maps_pauses() -> None:
    m = LabelMap.builtin("english_arpabet")
    got = [m.map_label(x) for x in ("sil", "sp", "AH0", "AH1", "ah2", "AA1", "L", "S", "SH", "HH",
                                    "IY0", "UW", "NG", "B")]
    # ARPAbet L and S are /l s/, not the model's palatal 'L' and postalveolar 'S'
    assert got == ["#", "#", "e", "a", "a", "a", "l", "s", "S", "h", "i", "u", "g", "b"]
    assert m.map_label("AH3") is None and m.map_label("XX") is None


def test_label_map_patterns(tmp_path: Path) -> None:
    tsv = _write(tmp_path, "m.tsv", "AH0\te\tschwa\nre:AH[12]?\ta\nre:(?i)p\tp\nre:[a-z]+\t=\n")
    m = resolve_label_map(tsv)
    # literal labels before patterns, patterns in file order, full matches only, '=' keeps the label
    assert [m.map_label(x) for x in ("AH0", "AH1", "AH", "P", "xy", "AH12")] == [
        "e", "a", "a", "p", "xy", None]
    assert resolve_label_map({"re:b+": "b"}).map_label("bbb") == "b"
    bad = _write(tmp_path, "bad.tsv", "a\ta\nre:(x\tb\n")
    with pytest.raises(DataError, match=r"bad\.tsv, line 2: pattern 're:\(x' is not a valid regular"):
        resolve_label_map(bad)


def test_label_map_record_round_trips_through_a_table(tmp_path: Path) -> None:
    from coartic.table import ParameterTable, TableError

    table = ParameterTable.load(Path(__file__).parents[1] / "data/fitted/quick_llo_table.json")
    assert LabelMap.recorded(table) == LabelMap.model()  # what `coartic fit` wrote
    m = LabelMap.builtin("english_arpabet")
    m.record_in(table)
    table.save(tmp_path / "t.json")
    back = LabelMap.recorded(ParameterTable.load(tmp_path / "t.json"))
    assert back is not None and back.name == "english_arpabet"
    for label in ("AH0", "sh", "sil", "K", "OW1"):
        assert back.map_label(label) == m.map_label(label)
    table.metadata["label_map"] = {"entries": [["a", 3]]}
    with pytest.raises(TableError, match=r"metadata\.label_map: entry \['a', 3\] is not"):
        LabelMap.recorded(table)
    del table.metadata["label_map"]
    assert LabelMap.recorded(table) is None


def test_tsv_malformed_first_row_is_an_error_not_a_header(tmp_path: Path) -> None:
    p = _write(tmp_path, "a.tsv", "0.0x\t0.3\tsil\n0.3\t0.5\ta\n")
    with pytest.raises(DataError, match=r"a\.tsv, line 1: expected times in seconds, found '0\.0x'"):
        read_labels(p)
    assert len(read_labels(_write(tmp_path, "h.tsv", "tmin\ttmax\ttext\n0\t0.3\tsil\n"))) == 1
    assert len(read_labels(_write(tmp_path, "h2.tsv", "t0\tt1\tphone\n0\t0.3\tsil\n"))) == 1
    with pytest.raises(DataError, match=r"b\.tsv, line 2: expected times in seconds, found '0\.5014abc'"):
        read_labels(_write(tmp_path, "b.tsv", "0\t0.3\tsil\n0.5014abc\t0.6\ta\n"))


def test_missing_label_is_an_error_not_a_pause(tmp_path: Path) -> None:
    with pytest.raises(DataError, match=r"m\.tsv, line 2: no label after the times 0\.3 0\.5"):
        read_labels(_write(tmp_path, "m.tsv", "0\t0.3\tsil\n0.3\t0.5\n0.5\t0.7\ta\n"))
    with pytest.raises(DataError, match=r"w\.txt, line 2: no label"):
        read_labels(_write(tmp_path, "w.txt", "0 0.3 sil\n0.3 0.5\n"))
    with pytest.raises(DataError, match=r"x\.lab, line 4: .*no label"):
        read_labels(_write(tmp_path, "x.lab", "separator ;\n#\n0.3 125 pau\n0.5 125\n"))
    # an explicitly empty cell is Praat's empty interval: a pause
    assert read_labels(_write(tmp_path, "e.tsv", "0\t0.3\t\n0.3\t0.5\ta\n")).labels == ("", "a")


def test_textgrid_size_that_undercounts_and_malformed_numbers(tmp_path: Path) -> None:
    # five intervals, size = 3: the two after the third must not be dropped silently
    tg = LONG_TG.replace("intervals: size = 5", "intervals: size = 3")
    with pytest.raises(DataError, match=r"c\.TextGrid, line \d+: tier 'phones' holds more items than "
                                        r"its size says: unexpected '0\.55'"):
        read_labels(_write(tmp_path, "c.TextGrid", tg))
    tg2 = LONG_TG.replace("points: size = 1", "points: size = 0")
    with pytest.raises(DataError, match=r"expected the class of tier 2, found '0\.5' \(does the size "
                                        r"of tier 'events' count all its items\?\)"):
        read_labels(_write(tmp_path, "d.TextGrid", tg2))
    tg3 = LONG_TG.replace("xmax = 0.45", "xmax = 0.45abc")
    with pytest.raises(DataError, match=r"f\.TextGrid, line \d+: malformed number '0\.45abc'"):
        read_labels(_write(tmp_path, "f.TextGrid", tg3))


def test_json_label_and_role_maps_refuse_duplicate_keys(tmp_path: Path) -> None:
    from coartic.io.roles import RoleMap

    m = _write(tmp_path, "m.json", '{"aa": "a",\n "aa": "o"}')
    with pytest.raises(DataError, match=r"m\.json: line 2: key 'aa' appears twice in one object"):
        resolve_label_map(m)
    r = _write(tmp_path, "r.json", '{"UL": "ul", "UL": "ll"}')
    with pytest.raises(DataError, match=r"r\.json: line 1: key 'UL' appears twice"):
        RoleMap.from_file(r)


# "the cat chose iron" as MFA's english_mfa model writes it: IPA phones, aspiration, length,
# diphthongs, a syllabic dark l, spoken noise
MFA_IPA = ("", "ð", "ə", "kʰ", "æ", "t", "tʃ", "ow", "z", "spn", "aj", "ɚ", "n", "ɫ̩", "iː", "ɡ", "ɹ", "ɝ", "")
MFA_IPA_PHONEMES = ("#", "d", "e", "k", "a", "t", "tS", "o", "z", "#", "a", "e", "n", "l", "i", "g", "r", "e", "#")


def _mfa_ipa_textgrid(path: Path) -> Path:
    ends = np.cumsum([0.3] + [0.09] * (len(MFA_IPA) - 2) + [0.3])
    starts = np.concatenate([[0.0], ends[:-1]])
    xmax = float(ends[-1])
    return write_textgrid(path, [
        ("words", [(0.0, 0.3, ""), (0.3, float(ends[-2]), "the cat chose iron"), (float(ends[-2]), xmax, "")]),
        ("phones", [(float(s), float(e), lab) for s, e, lab in zip(starts, ends, MFA_IPA)])])


def test_mfa_ipa_textgrid_is_read_with_the_ipa_map(tmp_path: Path) -> None:
    # MFA's IPA models (english_mfa, german_mfa, ...) write IPA phones: the built-in map 'ipa'
    # (labelmaps/phones_ipa.tsv, also alignment by synthesis' phone map) reads them, and the default
    # map's error points to it
    seg = read_labels(_mfa_ipa_textgrid(tmp_path / "cat.TextGrid"))
    assert seg.labels == MFA_IPA
    with pytest.raises(DataError, match=r"phone 'ð' .*the built-in map ipa maps every label of this file: "
                                        r"--label-map ipa"):
        LabelMap.model().apply(seg)
    assert resolve_label_map("ipa").apply(seg).labels == MFA_IPA_PHONEMES
    m = LabelMap.builtin("ipa")
    assert [m.map_label(x) for x in ("ˈa", "pʰ", "t̪", "ʉː", "ʔ", "sil", "sp", "ts", "tsʰ")] == [
        "a", "p", "t", "u", "#", "#", "#", "ts", "ts"]
    assert m.map_label("ǃ") is None and m.map_label("AA1") is None
    assert LabelMap.from_record(m.to_record()) == m  # a table fitted with it records it whole
