"""Reading a user's text file (spec, manifest, labels, label and role maps, table, CSV) with an error
that helps: the one way every such file is decoded.

Python's own ``UnicodeDecodeError`` names neither the file nor where in it the bad byte is, and
says nothing of what the file probably is. ``read_text`` names the file, the line and column, the
byte, and the encoding the file does decode as (the usual culprits of hand-edited files: a
Windows or Latin-1 editor), so the user knows what to convert. A byte-order mark is honoured: UTF-8
with a BOM (Excel's "CSV UTF-8") and UTF-16 with a BOM (Praat writes its TextGrids so as soon as a
label is not ASCII) are read as what they say they are.
"""

from __future__ import annotations

import codecs
from pathlib import Path

from coartic.errors import CoarticError

# A leading byte-order mark names the encoding (UTF-16 only with its BOM: without one it decodes
# anything of even length).
_BOMS = ((codecs.BOM_UTF8, "utf-8-sig"), (codecs.BOM_UTF16_LE, "utf-16"), (codecs.BOM_UTF16_BE, "utf-16"))
# Tried in this order when UTF-8 fails: the Windows code page before Latin-1, which decodes every byte.
_CANDIDATES = ("cp1252", "latin-1")


class TextDecodeError(CoarticError, ValueError):
    """A text file that does not decode: the message names the file, the place, and the encoding
    found. Attributes: ``path``, ``line`` and ``column`` (from 1), ``byte`` (its value), ``encoding``
    (what it was read as), ``found`` (the encoding it does decode as, or None) and ``detail`` (the
    message without the file, for callers that put the file in their own error)."""

    def __init__(self, path: str | Path, line: int, column: int, byte: int, encoding: str, found: str | None,
                 what: str) -> None:
        self.path, self.line, self.column, self.byte = Path(path), line, column, byte
        self.encoding, self.found = encoding, found
        place = f"line {line}, column {column}: byte 0x{byte:02x} is not {encoding.upper()}"
        if encoding == "utf-16":
            self.detail = f"{place}, though the file starts with UTF-16's byte-order mark; save this {what} as UTF-8"
        elif found:
            self.detail = (f"{place}; this {what} must be UTF-8 text, and it decodes as {found}: save it as UTF-8 "
                           f"(e.g. `iconv -f {found} -t utf-8`)")
        else:
            self.detail = f"{place}; this {what} must be UTF-8 text, and no common encoding decodes it: is it a text file?"
        super().__init__(f"{path}: {self.detail}")


def guess_encoding(data: bytes) -> str | None:
    """The first of Windows-1252 and Latin-1 that decodes ``data``, or None."""
    for name in _CANDIDATES:
        try:
            data.decode(name)
        except UnicodeDecodeError:
            continue
        return name
    return None


def decode_text(data: bytes, source: str | Path, what: str = "file") -> str:
    """``data`` as text: by its byte-order mark (dropped), else as UTF-8; a TextDecodeError naming
    ``source``, the line, column and byte, and the encoding it does decode as."""
    encoding, skip = "utf-8", 0
    for bom, name in _BOMS:
        if data.startswith(bom):
            encoding, skip = name, len(bom)
            break
    try:
        return data.decode(encoding)
    except UnicodeDecodeError as e:
        # utf-8-sig counts positions after its BOM, utf-16 from the start of the data
        start = min(e.start + (skip if encoding == "utf-8-sig" else 0), len(data) - 1)
        if encoding == "utf-16":
            body = data[skip:start].decode("utf-16-le" if data.startswith(codecs.BOM_UTF16_LE) else "utf-16-be",
                                           "replace")
            line, column = body.count("\n") + 1, len(body) - (body.rfind("\n") + 1) + 1
        else:
            line = data.count(b"\n", skip, start) + 1
            column = start - max(data.rfind(b"\n", skip, start) + 1, skip) + 1
        found = guess_encoding(data) if encoding.startswith("utf-8") else None
        raise TextDecodeError(source, line, column, data[start], encoding.removesuffix("-sig"), found, what) from None


def read_text(path: str | Path, what: str = "file") -> str:
    """The text of ``path`` (``decode_text``); OSError as usual, TextDecodeError naming file and place."""
    return decode_text(Path(path).read_bytes(), path, what)
