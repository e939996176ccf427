"""Fuzzing the readers: whatever the bytes, they return a result or raise DataError, nothing else."""

from __future__ import annotations

import atexit
import functools
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from coartic.io import DataError, load_trial, read_labels
from coartic.io.c3d import read_c3d
from coartic.io.labelmap import LabelMap

REAL = Path(__file__).parents[1] / "data/realdata"
OPTOTRAK = (REAL / "c3d-optotrak/Optotrak.c3d").read_bytes()
EMA_HEAD = "\n".join(
    (REAL / "emu-ema-german/derived/dfgspp_mo1_prosody_0020_ema.csv").read_text().splitlines()[:40]
) + "\n"
SEGMENTS = (REAL / "emu-ema-german/derived/dfgspp_mo1_prosody_0020_Segment.tsv").read_text()
TEXTGRID = '''File type = "ooTextFile"
Object class = "TextGrid"

xmin = 0
xmax = 0.7
tiers? <exists>
size = 1
item []:
    item [1]:
        class = "IntervalTier"
        name = "phones"
        xmin = 0
        xmax = 0.7
        intervals: size = 3
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
            xmax = 0.7
            text = "p"
'''
HTK = "0 3000000 sil\n3000000 4500000 a\n4500000 7000000 p\n"
XLABEL = "separator ;\nnfields 1\n#\n0.300 125 pau\n0.450 125 a\n0.700 125 p\n"
MARKERS_CSV = "time_s,UL_x,UL_y,UL_z,LL_x,LL_y,LL_z\n" + "".join(
    f"{i / 100:.2f},{i},1.5,2.5,,{i * 0.5},3\n" for i in range(12))

FUZZ = settings(max_examples=120, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


@st.composite
def mutated(draw: st.DrawFn, base: bytes, protect: int = 0) -> bytes:
    """`base` with a few bytes changed, cut, or spliced; the first `protect` bytes are kept."""
    b = bytearray(base)
    for _ in range(draw(st.integers(1, 6))):
        kind = draw(st.sampled_from(["set", "cut", "insert", "delete"]))
        pos = draw(st.integers(protect, max(protect, len(b) - 1)))
        if kind == "set" and pos < len(b):
            b[pos] = draw(st.integers(0, 255))
        elif kind == "cut":
            del b[max(pos, protect):]
        elif kind == "insert":
            b[pos:pos] = draw(st.binary(min_size=1, max_size=8))
        elif pos < len(b):
            del b[pos:pos + draw(st.integers(1, 16))]
    return bytes(b)


@functools.cache
def _scratch() -> Path:
    """One directory for the process's fuzzed files, removed at exit. A directory made and removed
    per example (tempfile.TemporaryDirectory) waited 3-4 ms on the file system's journal each (rmdir),
    6 s of the file's 2000 examples with the CPU idle; a file created and unlinked costs a
    hundredth of that (overwriting one in place would wait as long: ext4 flushes a truncated file)."""
    d = tempfile.TemporaryDirectory(prefix="coartic-fuzz-")
    atexit.register(d.cleanup)
    return Path(d.name)


def _only_data_error(data: bytes, suffix: str, read: Callable[[Path], Any]) -> None:
    p = _scratch() / f"fuzz{suffix}"  # alone in the directory: it is removed after each example
    p.write_bytes(data)
    try:
        read(p)
    except DataError:
        pass
    finally:
        p.unlink()


@pytest.mark.slow
@FUZZ
@given(data=st.one_of(mutated(OPTOTRAK, protect=2), st.binary(max_size=2000)))
def test_c3d_fuzz_ezc3d(data: bytes) -> None:
    _only_data_error(data, ".c3d", lambda p: read_c3d(p, allow_truncated=True))


@pytest.mark.slow
@FUZZ
@given(data=mutated(OPTOTRAK, protect=2))
def test_c3d_fuzz_pure_python_fallback(data: bytes) -> None:
    _only_data_error(data, ".c3d", lambda p: read_c3d(p, backend="c3d"))


def _text_cases(base: str) -> st.SearchStrategy[bytes]:
    return st.one_of(
        mutated(base.encode()),
        st.text(max_size=400).map(lambda s: s.encode("utf-8", "surrogatepass")),
        st.lists(st.sampled_from(base.splitlines()), max_size=30).map(
            lambda lines: "\n".join(lines).encode()),
    )


@FUZZ
@given(data=_text_cases(TEXTGRID))
def test_textgrid_fuzz(data: bytes) -> None:
    _only_data_error(data, ".TextGrid", read_labels)


@FUZZ
@given(data=st.one_of(_text_cases(HTK), _text_cases(XLABEL)))
def test_lab_fuzz(data: bytes) -> None:
    _only_data_error(data, ".lab", lambda p: LabelMap({}, keep_unmapped=True).apply(read_labels(p)))


@FUZZ
@given(data=_text_cases(SEGMENTS))
def test_tsv_labels_fuzz(data: bytes) -> None:
    _only_data_error(data, ".tsv", lambda p: LabelMap.builtin("german_sampa").apply(read_labels(p)))


@FUZZ
@given(data=_text_cases(MARKERS_CSV))
def test_marker_csv_fuzz(data: bytes) -> None:
    _only_data_error(data, ".csv", lambda p: load_trial(p).channels())


@pytest.mark.slow
@FUZZ
@given(data=_text_cases(EMA_HEAD))
def test_ema_csv_fuzz(data: bytes) -> None:
    _only_data_error(data, ".csv", load_trial)


def _ssff_track() -> bytes:
    import base64
    import json

    bundle = json.loads((REAL / "emu-ema-german/dfgspp_mo1_prosody_0020_bndl.json").read_text())
    track = next(f for f in bundle["ssffFiles"] if f["fileExtension"] == "upper_lip")
    raw = base64.b64decode(track["data"])
    return raw[: raw.find(b"-----------------\n") + 18 + 24 * 40]  # header + 40 whole records


SSFF = _ssff_track()


@FUZZ
@given(data=st.one_of(mutated(SSFF), st.binary(max_size=600)))
def test_ssff_fuzz(data: bytes) -> None:
    from coartic.io.emu import parse_ssff

    try:
        parse_ssff(data, "fuzz")
    except DataError:
        pass


def _small_bundle() -> str:
    import base64
    import json

    track = base64.b64encode(SSFF).decode()
    ll = base64.b64encode(SSFF.replace(b"ul_pos", b"ll_pos").replace(b"ul_ori", b"ll_ori")).decode()
    items = [{"id": i, "sampleStart": 240 * i, "sampleDur": 240,
              "labels": [{"name": "Segment", "value": v}]} for i, v in enumerate(["&p:", "a", "m"])]
    return json.dumps({"ssffFiles": [{"fileExtension": "upper_lip", "encoding": "BASE64",
                                      "data": track},
                                     {"fileExtension": "lower_lip", "encoding": "BASE64", "data": ll}],
                       "annotation": {"sampleRate": 24000, "levels": [
                           {"name": "Segment", "type": "SEGMENT", "items": items}]}}, indent=1)


@FUZZ
@given(data=st.one_of(mutated(_small_bundle().encode()),
                      st.lists(st.sampled_from(_small_bundle().splitlines()), max_size=40).map(
                          lambda lines: "\n".join(lines).encode())))
def test_emu_bundle_fuzz(data: bytes) -> None:
    _only_data_error(data, ".json", lambda p: load_trial(p, label_map="german_sampa").channels())


@FUZZ
@given(data=_text_cases("aa\ta\tlong a\nQ\t=\n*\t=\n"))
def test_label_map_fuzz(data: bytes) -> None:
    _only_data_error(data, ".tsv", LabelMap.from_file)


def _fixture_bytes(write: Callable[[Path], Path]) -> bytes:
    with tempfile.TemporaryDirectory() as d:
        return write(Path(d)).read_bytes()


def _read_quietly(p: Path) -> None:
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # implausible values warn; only exceptions matter here
        load_trial(p).channels()


def _formats() -> dict[str, bytes]:
    import format_fixtures as ff

    m = ff.motion(50.0)
    return {
        ".ema": _fixture_bytes(lambda d: ff.write_mocha_est(d / "a.ema", m)),
        ".est": _fixture_bytes(lambda d: ff.write_mocha_est(d / "a.est", m, binary=False)),
        ".txy": _fixture_bytes(lambda d: ff.write_txy(d / "a.txy", m, lost={"T4": (2,)})),
        ".mat": _fixture_bytes(lambda d: ff.write_mview(d / "a.mat", m, audio_rate=100.0)),
        "lab.csv": _fixture_bytes(lambda d: ff.write_lab_csv(d / "a.csv", m, planar=True)),
    }


FORMATS = _formats()


@pytest.mark.parametrize("suffix", sorted(FORMATS))
def test_corpus_formats_fuzz(suffix: str) -> None:
    # the header (text) is kept intact in part of the cases so that the frames are reached
    @FUZZ
    @given(data=st.one_of(mutated(FORMATS[suffix]), mutated(FORMATS[suffix], protect=200),
                          st.binary(max_size=600)))
    def fuzz(data: bytes) -> None:
        _only_data_error(data, suffix if suffix != "lab.csv" else ".csv", _read_quietly)

    fuzz()


@FUZZ
@given(data=_text_cases("0 3050 h#\n3050 4559 sh\n4559 5723 ix\n"))
def test_timit_phn_fuzz(data: bytes) -> None:
    _only_data_error(data, ".phn", lambda p: LabelMap.builtin("timit").apply(read_labels(p)))
