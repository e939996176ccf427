"""Every user text file is decoded by one function (coartic.textfile.read_text), so a file that is
not UTF-8 is named the same way whichever reader meets it: the file, line and column, the byte,
and the encoding it does decode as (issue 21 item 2)."""

from __future__ import annotations

import codecs
from pathlib import Path
from typing import Any, Callable

import pytest

from coartic.errors import CoarticError
from coartic.textfile import TextDecodeError, decode_text, read_text


def test_the_error_names_file_place_byte_and_encoding_found() -> None:
    with pytest.raises(TextDecodeError) as e:
        decode_text(b"a,b\nc\xe9,d\n", "m.csv", "manifest")
    assert str(e.value) == ("m.csv: line 2, column 2: byte 0xe9 is not UTF-8; this manifest must be UTF-8 text, "
                            "and it decodes as cp1252: save it as UTF-8 (e.g. `iconv -f cp1252 -t utf-8`)")
    err = e.value
    assert (err.path, err.line, err.column, err.byte, err.encoding, err.found) == (Path("m.csv"), 2, 2, 0xE9, "utf-8",
                                                                                   "cp1252")
    assert isinstance(err, CoarticError) and isinstance(err, ValueError)


def test_byte_order_marks_are_honoured() -> None:
    assert decode_text(codecs.BOM_UTF8 + "é".encode(), "x") == "é"  # Excel's "CSV UTF-8"
    assert decode_text("a\tʃ\n".encode("utf-16"), "x") == "a\tʃ\n"  # Praat's TextGrids
    with pytest.raises(TextDecodeError, match=r"x: line 1, column 2: byte 0xe9 is not UTF-8"):
        decode_text(codecs.BOM_UTF8 + b"a\xe9", "x")  # columns count after the mark
    with pytest.raises(TextDecodeError, match="not UTF-16, though the file starts with UTF-16's byte-order mark"):
        decode_text("ab".encode("utf-16") + b"\x00\xd8", "x")


LATIN1 = "é".encode("latin-1")


def _spec(tmp: Path) -> Any:
    from coartic.fit.spec import load_spec

    p = tmp / "s.toml"
    p.write_bytes(b'[corpus]\nmanifest = "m.csv"\n# caf' + LATIN1 + b"\n")
    return p, lambda: load_spec(p), 3


def _labels(tmp: Path) -> Any:
    from coartic.io.labels import read_labels

    p = tmp / "a.lab"
    p.write_bytes(b"0.0 0.1 a\n0.1 0.2 " + LATIN1 + b"\n")
    return p, lambda: read_labels(p), 2


def _table(tmp: Path) -> Any:
    from coartic.table import ParameterTable

    p = tmp / "t.json"
    p.write_bytes(b'{\n"schema": "coartic.table/1",\n"variant": "' + LATIN1 + b'"}\n')
    return p, lambda: ParameterTable.load(p), 3


def _label_map(tmp: Path) -> Any:
    from coartic.io.labelmap import LabelMap

    p = tmp / "m.tsv"
    p.write_bytes(b"a\ta\n" + LATIN1 + b"\te\n")
    return p, lambda: LabelMap.from_file(p), 2


def _role_map(tmp: Path) -> Any:
    from coartic.io.roles import RoleMap

    p = tmp / "r.json"
    p.write_bytes(b'{\n"UL": "' + LATIN1 + b'"}\n')
    return p, lambda: RoleMap.from_file(p), 2


def _markers(tmp: Path) -> Any:
    from coartic.io.markers_csv import read_markers_csv

    p = tmp / "m.csv"
    p.write_bytes(b"time,UL_x\n0.0,1.0\n0.01," + LATIN1 + b"\n")
    return p, lambda: read_markers_csv(p), 3


def _manifest(tmp: Path) -> Any:
    from coartic.fit.data import manifest_rows
    from coartic.fit.spec import parse_spec

    p = tmp / "m.csv"
    p.write_bytes(b"file,labels\ns" + LATIN1 + b".c3d,a.lab\n")
    spec = parse_spec({"corpus": {"manifest": "m.csv"}}, tmp / "s.toml")
    return p, lambda: manifest_rows(spec), 2


def _batch_manifest(tmp: Path) -> Any:
    from coartic.batch.spec import load_batch_spec

    (tmp / "fit.toml").write_text('[corpus]\nmanifest = "m.csv"\n')
    p = tmp / "m.csv"
    p.write_bytes(b"file,labels,speaker\ns" + LATIN1 + b".c3d,a.lab,s1\n")
    b = tmp / "batch.toml"
    b.write_text('fit = "fit.toml"\n[corpus]\nmanifest = "m.csv"\ngroup_by = ["speaker"]\n')
    return p, lambda: load_batch_spec(b), 2


@pytest.mark.parametrize("make", [_spec, _labels, _table, _label_map, _role_map, _markers, _manifest, _batch_manifest])
def test_every_reader_of_user_text_names_file_line_and_encoding(tmp_path: Path,
                                                                make: Callable[[Path], Any]) -> None:
    path, read, line = make(tmp_path)
    with pytest.raises(CoarticError) as e:
        read()
    assert str(path) in str(e.value)
    assert f"line {line}" in str(e.value) and "byte 0xe9 is not UTF-8" in str(e.value), str(e.value)
    assert "it decodes as cp1252" in str(e.value)


def test_read_text_leaves_os_errors_alone(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        read_text(tmp_path / "absent.txt")
