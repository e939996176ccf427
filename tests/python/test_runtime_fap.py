"""MPEG-4 FAP files and the channel → FAP mapping (coartic.runtime.fap)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from coartic.runtime.errors import AnimationError, FapFormatError
from coartic.runtime.fap import (
    FAP_NAMES,
    LIP_JAW_FAPS,
    N_FAPS,
    FaceUnits,
    FapSequence,
    channels_to_faps,
    read_fap,
    write_fap,
)

NEUTRAL = {"ULO": 0.0, "LLO": 0.0, "ULP": 98.0, "LLP": 95.0, "LR": 50.0, "JO": 115.0}


@st.composite
def fap_sequences(draw: st.DrawFn) -> FapSequence:
    n = draw(st.integers(0, 6))
    mask = np.array(draw(st.lists(st.lists(st.booleans(), min_size=N_FAPS, max_size=N_FAPS),
                                  min_size=n, max_size=n)), dtype=bool).reshape(n, N_FAPS)
    mask[:, 0] = False  # the viseme is a high-level FAP coartic does not write, refused (tested below)
    values = np.array(draw(st.lists(st.integers(-(2**40), 2**40), min_size=n * N_FAPS, max_size=n * N_FAPS)),
                      dtype=np.int64).reshape(n, N_FAPS)
    # the expression (FAP 2): six fields where sent, each within its range
    fields = np.array([[draw(st.integers(0, 6)), draw(st.integers(0, 63)), draw(st.integers(0, 6)),
                        draw(st.integers(0, 63)), draw(st.integers(0, 1)), draw(st.integers(0, 1))] for _ in range(n)],
                      dtype=np.int64).reshape(n, 6)
    name = draw(st.text(st.characters(min_codepoint=33, max_codepoint=126), min_size=1, max_size=12))
    fps = draw(st.one_of(st.integers(1, 200).map(float), st.floats(0.01, 1000.0, allow_nan=False)))
    first = draw(st.integers(0, 5))
    return FapSequence(name=name, fps=fps, mask=mask, values=values, first_frame=first,
                       expression=fields if mask[:, 1].any() else None)


@settings(max_examples=60, deadline=None)
@given(seq=fap_sequences())
def test_fap_file_round_trip(tmp_path_factory: pytest.TempPathFactory, seq: FapSequence) -> None:
    path = tmp_path_factory.mktemp("fap") / "x.fap"
    write_fap(path, seq)
    back = read_fap(path)
    assert back.same_as(seq)
    # what was not sent reads back as 0, whatever the writer's array held there
    assert np.all(back.values[~back.mask] == 0)


def test_fap_file_layout(tmp_path: Path) -> None:
    mask = np.zeros((2, N_FAPS), dtype=bool)
    mask[:, [2, 3]] = True
    values = np.zeros((2, N_FAPS), dtype=np.int64)
    values[0, [2, 3]] = [120, -7]
    values[1, [2, 3]] = [0, 5]
    write_fap(tmp_path / "a.fap", FapSequence("ciao", 25.0, mask, values))
    lines = (tmp_path / "a.fap").read_text().splitlines()
    assert lines[0] == "2.1 ciao 25 2"
    assert lines[1].split() == ["0", "0", "1", "1"] + ["0"] * 64
    assert lines[2] == "0 120 -7"
    assert lines[4] == "1 0 5"
    assert len(lines) == 5


GOOD = "2.1 test 25 2\n" + " ".join(["0", "0", "1"] + ["0"] * 65) + "\n0 10\n" + " ".join(["0", "0", "1"] + ["0"] * 65) + "\n1 12\n"


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("", "empty file"),
        ("2.0 test 25 2\n", "line 1: header"),
        ("2.1 test fast 2\n", "line 1: fps 'fast'"),
        ("2.1 test 25 two\n", "line 1: frame count 'two'"),
        (GOOD.replace("\n1 12\n", "\n"), "announces 2 frames"),
        (GOOD.replace(" ".join(["0", "0", "1"] + ["0"] * 65), " ".join(["0", "0", "1"] + ["0"] * 64), 1), "line 2"),
        (GOOD.replace("0 0 1 0", "0 0 2 0", 1), "line 2: frame 0 mask"),
        (GOOD.replace("\n0 10\n", "\n0 1.5\n"), "line 3: '1.5' is not an integer"),
        (GOOD.replace("\n0 10\n", "\n0 10 11\n"), "line 3: frame 0 has 2 values but its mask (line 2) selects 1"),
        (GOOD.replace("\n1 12\n", "\n3 12\n"), "line 5: frame number 3, expected 1"),
        (GOOD.replace("0 0 1 0", "1 0 1 0", 1), "line 2: FAP 1 (viseme) is set"),
        # FAP 2 takes six values (expression_select1 .. expression_def), each within its range
        (GOOD.replace("0 0 1 0", "0 1 1 0", 1), "line 3: frame 0 has 1 values but its mask (line 2) selects 2 FAPs "
                                                "(7 values: FAP 2 takes 6)"),
        (GOOD.replace("0 0 1 0", "0 1 1 0", 1).replace("\n0 10\n", "\n0 7 10 0 0 0 0 10\n"),
         "line 3: frame 0: FAP 2 (expression): expression_select1 = 7 is not within 0-6"),
    ],
)
def test_malformed_fap_files_name_the_line(tmp_path: Path, text: str, needle: str) -> None:
    path = tmp_path / "bad.fap"
    path.write_text(text)
    with pytest.raises(FapFormatError) as err:
        read_fap(path)
    assert str(path) in str(err.value)
    assert needle in str(err.value)


def test_missing_fap_file_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(FapFormatError, match="cannot read"):
        read_fap(tmp_path / "nothere.fap")


def test_fap_names_follow_mpeg4() -> None:
    assert len(FAP_NAMES) == 68
    assert FAP_NAMES[2] == "open_jaw" and FAP_NAMES[3] == "lower_t_midlip" and FAP_NAMES[4] == "raise_b_midlip"
    assert FAP_NAMES[15] == "push_b_lip" and FAP_NAMES[16] == "push_t_lip"
    assert FAP_NAMES[50] == "lower_t_midlip_o" and FAP_NAMES[59] == "raise_r_cornerlip_o"
    assert LIP_JAW_FAPS == (3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 16, 17, *range(51, 61))


def _one_frame(**delta: float) -> dict[str, np.ndarray]:
    return {c: np.array([NEUTRAL[c] + delta.get(c, 0.0)]) for c in NEUTRAL}


def test_mapping_units_and_signs() -> None:
    face = FaceUnits(mns_mm=32.0, mw_mm=51.2)  # FAPU = 1/32 mm and 1/20 mm
    seq = channels_to_faps(
        _one_frame(ULO=2.0, LLO=10.0, ULP=1.0, LLP=-0.5, LR=-4.0, JO=6.0), NEUTRAL, face, "t", 25.0
    )
    v = {f: int(seq.column(f)[0]) for f in LIP_JAW_FAPS}
    assert v[3] == 6 * 32  # open_jaw: positive down, the jaw opened 6 mm
    assert v[4] == -2 * 32  # lower_t_midlip: positive down; the upper lip went up 2 mm
    assert v[5] == -10 * 32  # raise_b_midlip: positive up; the lower lip went down 10 mm
    assert v[6] == v[7] == -2 * 20  # each corner moved 2 mm inwards (MW units)
    assert v[8] == v[9] == round(-2 * 32 * np.sqrt(3) / 2)
    assert v[10] == v[11] == round(-10 * 32 * np.sqrt(3) / 2)
    assert v[12] == v[13] == 0
    assert v[16] == -16 and v[17] == 32  # push: forwards positive
    for outer, inner in zip(range(51, 61), (4, 5, 6, 7, 8, 9, 10, 11, 12, 13)):
        assert v[outer] == v[inner]
    assert set(np.flatnonzero(seq.mask[0]) + 1) == set(LIP_JAW_FAPS)


def test_neutral_face_gives_zero_faps_and_jaw_is_unidirectional() -> None:
    seq = channels_to_faps(_one_frame(), NEUTRAL, FaceUnits(), "n", 25.0)
    assert np.all(seq.values == 0)
    closed = channels_to_faps(_one_frame(JO=-1.0), NEUTRAL, FaceUnits(), "n", 25.0)
    assert closed.column(3)[0] == 0


def test_mapping_rejects_bad_channels_and_units() -> None:
    chans = _one_frame()
    del chans["LR"]
    with pytest.raises(AnimationError, match="missing LR"):
        channels_to_faps(chans, NEUTRAL, FaceUnits(), "n", 25.0)
    chans = _one_frame()
    chans["JO"] = np.array([np.nan])
    with pytest.raises(AnimationError, match="channel JO is not finite at frame 0"):
        channels_to_faps(chans, NEUTRAL, FaceUnits(), "n", 25.0)
    with pytest.raises(AnimationError, match="mns_mm"):
        FaceUnits(mns_mm=0.0)
    high = np.zeros((1, N_FAPS), bool)
    high[0, 1] = True
    with pytest.raises(AnimationError, match=r"FAP 2 \(expression\) is sent without its six values"):
        FapSequence("x", 25.0, high, np.zeros((1, N_FAPS), np.int64))
    with pytest.raises(AnimationError, match=r"frame 0: FAP 2 \(expression\): expression_intensity1 = 64"):
        FapSequence("x", 25.0, high, np.zeros((1, N_FAPS), np.int64), expression=np.array([[1, 64, 0, 0, 0, 0]]))
    high[0, 0] = True
    with pytest.raises(AnimationError, match=r"FAP 1 \(viseme\) is a high-level FAP"):
        FapSequence("x", 25.0, high, np.zeros((1, N_FAPS), np.int64), expression=np.zeros((1, 6), np.int64))
    with pytest.raises(AnimationError, match="one word"):
        FapSequence("two words", 25.0, np.zeros((0, N_FAPS), bool), np.zeros((0, N_FAPS), np.int64))
