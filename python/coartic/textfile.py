"""Reading a user's text file (spec, labels, label map, table, CSV) with an error that helps.

Python's own ``UnicodeDecodeError`` names neither the file nor where in it the bad byte is, and
says nothing of what the file probably is. ``read_text`` names the file, the line and column, the
byte, and the encoding the file does decode as (the usual culprits of hand-edited files: a
Windows or Latin-1 editor, or UTF-16 from some exporters), so the user knows what to convert.
"""

from __future__ import annotations

import codecs
from pathlib import Path

from coartic.errors import CoarticError

# Tried in this order when UTF-8 fails: UTF-16 only with its byte-order mark (it decodes anything
# of even length otherwise), then the Windows code page before Latin-1, which decodes every byte.
_CANDIDATES = (("utf-16", (codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)), ("cp1252", ()), ("latin-1", ()))


class TextDecodeError(CoarticError, ValueError):
    """A text file that is not UTF-8: the message names the file, the place, and the encoding found."""


def guess_encoding(data: bytes) -> str | None:
    """The first of UTF-16 (with BOM), Windows-1252 and Latin-1 that decodes ``data``, or None."""
    for name, boms in _CANDIDATES:
        if boms and not data.startswith(boms):
            continue
        try:
            data.decode(name)
        except UnicodeDecodeError:
            continue
        return name
    return None


def decode_text(data: bytes, source: str | Path, what: str = "file") -> str:
    """``data`` decoded as UTF-8 (a leading BOM dropped), or a TextDecodeError naming ``source``."""
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        line = data.count(b"\n", 0, e.start) + 1
        column = e.start - (data.rfind(b"\n", 0, e.start) + 1) + 1
        found = guess_encoding(data)
        hint = (f"it decodes as {found}: save it as UTF-8 (e.g. `iconv -f {found} -t utf-8`)"
                if found else "no common encoding decodes it: is it a text file?")
        raise TextDecodeError(f"{source}: line {line}, column {column}: byte 0x{data[e.start]:02x} is not "
                              f"UTF-8; this {what} must be UTF-8 text, and {hint}") from None


def read_text(path: str | Path, what: str = "file") -> str:
    """The text of ``path`` as UTF-8; OSError as usual, TextDecodeError naming file and place."""
    return decode_text(Path(path).read_bytes(), path, what)
