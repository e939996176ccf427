"""Phone labels: Praat TextGrid (long and short text), HTK, MOCHA and Festival/xlabel .lab, TIMIT
.phn/.wrd, plain TSV.

Every reader returns `Segments` (label, start, end in seconds, with the source line of each
segment) and checks them: sorted, non-overlapping, positive durations. Labels are the corpus'
own; `coartic.io.labelmap` turns them into model phonemes.

TextGrid is parsed by hand (no PyPI parser is both maintained and strict about errors): like
Praat itself, the reader takes the numbers, quoted strings and <exists> flags in order and
skips the `name =` and `[n]:` decorations, so the long and the short text format are one format.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from coartic.io.errors import DataError
from coartic.textfile import TextDecodeError, read_text

# Two segments may touch with this much rounding (labels are often written with 5-6 decimals).
TIME_TOLERANCE = 1e-6
HTK_UNITS_PER_SECOND = 1e7  # HTK times are in 100 ns units
TIMIT_SAMPLE_RATE = 16000.0  # TIMIT .phn/.wrd times are sample numbers of its 16 kHz audio
# A TextGrid tier whose name says it holds phones (Montreal Forced Aligner: "phones", or
# "<speaker> - phones"; WebMAUS: "MAU"; EMU: "Segment") is taken before the first interval tier
# (MFA writes the words tier first).
PHONE_TIER = re.compile(r"(?i)(^|[^a-z])(phones?|phonemes?|segments?|mau)$")


@dataclass(frozen=True)
class Segments:
    """Acoustic segments of one utterance: labels with start and end times in seconds."""

    labels: tuple[str, ...]
    starts: NDArray[np.float64]
    ends: NDArray[np.float64]
    source: Path | None = None
    lines: tuple[int | None, ...] = field(default=())
    tier: str | None = None
    tiers: tuple[str, ...] = ()  # every tier of the TextGrid it came from (for messages)

    def __post_init__(self) -> None:
        n = len(self.labels)
        starts = np.ascontiguousarray(self.starts, dtype=np.float64)
        ends = np.ascontiguousarray(self.ends, dtype=np.float64)
        object.__setattr__(self, "starts", starts)
        object.__setattr__(self, "ends", ends)
        if not self.lines:
            object.__setattr__(self, "lines", (None,) * n)
        if starts.shape != (n,) or ends.shape != (n,) or len(self.lines) != n:
            raise DataError(
                f"{n} labels but {starts.size} starts, {ends.size} ends", path=self.source
            )
        for i in range(n):
            where = self._where(i)
            s, e = float(starts[i]), float(ends[i])
            if not (np.isfinite(s) and np.isfinite(e)):
                raise DataError(f"label {self.labels[i]!r}{where} has a non-finite time",
                                path=self.source, line=self.lines[i], item=self.labels[i])
            if e <= s:
                raise DataError(
                    f"label {self.labels[i]!r}{where} ends at {e:g} s, not after its start {s:g} s",
                    path=self.source, line=self.lines[i], item=self.labels[i])
            if i and s < float(ends[i - 1]) - TIME_TOLERANCE:
                kind = "is out of order" if s < float(starts[i - 1]) else "overlaps"
                raise DataError(
                    f"label {self.labels[i]!r}{where} starting at {s:g} s {kind} the previous "
                    f"label {self.labels[i - 1]!r} ({float(starts[i - 1]):g}-{float(ends[i - 1]):g} s)",
                    path=self.source, line=self.lines[i], item=self.labels[i])

    def _where(self, i: int) -> str:
        return f" (segment {i + 1})"

    def __len__(self) -> int:
        return len(self.labels)

    @property
    def end_time(self) -> float:
        return float(self.ends[-1]) if len(self) else 0.0

    def with_labels(self, labels: Sequence[str]) -> Segments:
        """The same segments with other labels (the label map's output)."""
        return Segments(tuple(labels), self.starts, self.ends, self.source, self.lines, self.tier,
                        self.tiers)

    def shifted(self, offset: float) -> Segments:
        return Segments(self.labels, self.starts + offset, self.ends + offset, self.source,
                        self.lines, self.tier, self.tiers)

    def clipped(self, end: float, keep: int | None = None) -> Segments:
        """The first `keep` segments (default all) with the last of them ending at `end` (a label
        past the data: audio and sensors stop apart)."""
        k = len(self) if keep is None else keep
        ends = self.ends[:k].copy()
        ends[-1] = end
        return Segments(self.labels[:k], self.starts[:k], ends, self.source, self.lines[:k], self.tier,
                        self.tiers)

    def tier_note(self) -> str:
        """", tier 'words' of ['words', 'phones']" for messages ('' without tiers): a map that
        does not know a label may have been given the wrong tier."""
        if self.tier is None:
            return ""
        return f", tier {self.tier!r}" + (f" of {list(self.tiers)}" if len(self.tiers) > 1 else "")


def read_labels(path: str | PathLike[str], tier: str | None = None) -> Segments:
    """Read a label file, choosing the format from the extension and, failing that, the content.

    `tier` names the TextGrid interval tier to use (default: the first interval tier); it is an
    error to give it for formats that have no tiers. Times are seconds from the recording's
    start: a negative one is refused.
    """
    segs = _read_labels(Path(path), tier)
    if len(segs) and float(segs.starts[0]) < 0:
        raise DataError(f"label {segs.labels[0]!r} starts at {float(segs.starts[0]):g} s: label times are seconds "
                        "from the start of the recording, never negative (shift the labels, or cut the part "
                        "before 0 s)", path=segs.source, line=segs.lines[0], item=segs.labels[0])
    return segs


def _read_labels(p: Path, tier: str | None) -> Segments:
    text = _read_text(p)
    suffix = p.suffix.lower()
    if suffix == ".textgrid" or _looks_like_textgrid(text):
        return parse_textgrid(text, p, tier)
    if tier is not None:
        raise DataError(f"tier {tier!r} was asked for, but this is not a TextGrid", path=p)
    if suffix in (".phn", ".wrd"):
        return parse_timit(text, p)
    if suffix in (".lab", ".htk", ".mlf") or _looks_like_lab(text):
        return parse_lab(text, p)
    return parse_tsv(text, p)


def _read_text(p: Path) -> str:
    # coartic.textfile: UTF-8, or UTF-16 with its BOM (Praat's as soon as a label is not ASCII)
    try:
        text = read_text(p, "label file")
    except OSError as e:
        raise DataError(f"cannot read the label file: {e.strerror or e}", path=p) from None
    except TextDecodeError as e:
        raise DataError(e.detail, path=p) from None
    if "\x00" in text:
        raise DataError("contains NUL bytes: not a text label file", path=p)
    return text


def _looks_like_textgrid(text: str) -> bool:
    head = text.lstrip()[:200]
    return head.startswith("File type") and "TextGrid" in head


def _looks_like_lab(text: str) -> bool:
    return any(line.strip() == "#" for line in text.splitlines()[:50])


# --- Praat TextGrid -----------------------------------------------------------------------------

_TOKEN = re.compile(
    r'''(?P<str>"(?:[^"]|"")*")'''
    r"|(?P<flag><[A-Za-z]+>)"
    r"|(?P<comment>![^\n]*)"
    r"|(?P<key>[A-Za-z_][A-Za-z_ ]*?\s*(?:\[\s*\d*\s*\])?\s*[=:])"
    r"|(?P<word>[A-Za-z_]\w*\??)"
    r"|(?P<index>\[\s*\d*\s*\]\s*:?)"
    # a number must end where the token ends: "0.5014abc" is a malformed number, not 0.5014 and a word
    r"|(?P<num>[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?(?![\w.]))"
    r"|(?P<badnum>[-+]?(?:\d|\.\d)[\w.+-]*)"
    r"|(?P<space>\s+)"
    r"|(?P<bad>.)",
    re.DOTALL,
)


@dataclass
class _Tok:
    kind: str
    value: str
    line: int


class _TokenStream:
    def __init__(self, text: str, path: Path) -> None:
        self.path = path
        self.toks: list[_Tok] = []
        line = 1
        for m in _TOKEN.finditer(text):
            kind = m.lastgroup or "bad"
            value = m.group()
            if kind == "bad":
                raise DataError(f"unexpected character {value!r} in a TextGrid", path=path, line=line)
            if kind == "badnum":
                raise DataError(f"malformed number {value!r} in a TextGrid", path=path, line=line,
                                item=value)
            if kind in ("str", "flag", "num"):
                if kind == "str":
                    value = value[1:-1].replace('""', '"')
                self.toks.append(_Tok(kind, value, line))
            line += value.count("\n") if kind != "str" else m.group().count("\n")
        self.pos = 0
        self.last_line = line

    def _next(self, kind: str, what: str) -> _Tok:
        if self.pos >= len(self.toks):
            raise DataError(f"the TextGrid ends early: expected {what}", path=self.path,
                            line=self.last_line)
        tok = self.toks[self.pos]
        if tok.kind != kind:
            raise DataError(f"expected {what}, found {tok.value!r}", path=self.path, line=tok.line)
        self.pos += 1
        return tok

    def string(self, what: str) -> _Tok:
        return self._next("str", what)

    def number(self, what: str) -> tuple[float, int]:
        tok = self._next("num", what)
        value = float(tok.value)
        if not np.isfinite(value):
            raise DataError(f"{what} is not finite", path=self.path, line=tok.line)
        return value, tok.line

    def count(self, what: str, limit: int) -> int:
        value, line = self.number(what)
        if value != int(value) or value < 0 or value > limit:
            raise DataError(f"{what} = {value:g} is not a plausible count", path=self.path, line=line)
        return int(value)

    def at_end(self) -> bool:
        return self.pos >= len(self.toks)

    def peek(self) -> _Tok:
        return self.toks[self.pos]

    def flag(self) -> None:
        if self.pos < len(self.toks) and self.toks[self.pos].kind == "flag":
            tok = self.toks[self.pos]
            if tok.value != "<exists>":
                raise DataError(f"a TextGrid without tiers ({tok.value})", path=self.path,
                                line=tok.line)
            self.pos += 1


def parse_textgrid(text: str, path: Path, tier: str | None = None) -> Segments:
    ts = _TokenStream(text, path)
    ftype = ts.string('File type = "ooTextFile"')
    if ftype.value != "ooTextFile":
        raise DataError(f"file type {ftype.value!r} is not 'ooTextFile' (binary or chronological "
                        "TextGrids are not read; save as text from Praat)", path=path, line=ftype.line)
    oclass = ts.string('Object class = "TextGrid"')
    if oclass.value != "TextGrid":
        raise DataError(f"object class {oclass.value!r} is not 'TextGrid'", path=path,
                        line=oclass.line)
    ts.number("the TextGrid xmin")
    ts.number("the TextGrid xmax")
    ts.flag()
    limit = len(ts.toks)
    n_tiers = ts.count("the number of tiers", limit)
    names: list[str] = []
    interval: list[tuple[str, list[str], list[float], list[float], list[int]]] = []
    for t in range(n_tiers):
        if not ts.at_end() and ts.peek().kind != "str":
            hint = f" (does the size of tier {names[-1]!r} count all its items?)" if names else ""
            raise DataError(f"expected the class of tier {t + 1}, found {ts.peek().value!r}{hint}",
                            path=path, line=ts.peek().line)
        cls = ts.string(f"the class of tier {t + 1}")
        name = ts.string(f"the name of tier {t + 1}").value
        names.append(name)
        ts.number(f"xmin of tier {name!r}")
        ts.number(f"xmax of tier {name!r}")
        if cls.value == "IntervalTier":
            n = ts.count(f"the number of intervals of tier {name!r}", limit)
            labels, starts, ends, lines = [], [], [], []
            for k in range(n):
                s, line = ts.number(f"xmin of interval {k + 1} of tier {name!r}")
                e, _ = ts.number(f"xmax of interval {k + 1} of tier {name!r}")
                lab = ts.string(f"the text of interval {k + 1} of tier {name!r}").value
                labels.append(lab.strip())
                starts.append(s)
                ends.append(e)
                lines.append(line)
            if tier is None or tier == name:
                interval.append((name, labels, starts, ends, lines))
        elif cls.value == "TextTier":
            n = ts.count(f"the number of points of tier {name!r}", limit)
            for k in range(n):
                ts.number(f"the time of point {k + 1} of tier {name!r}")
                ts.string(f"the mark of point {k + 1} of tier {name!r}")
            if tier == name:
                raise DataError(f"tier {name!r} is a point tier; phone labels need an interval tier",
                                path=path, line=cls.line, item=name)
        else:
            raise DataError(f"tier class {cls.value!r} is neither IntervalTier nor TextTier",
                            path=path, line=cls.line, item=name)
    if not ts.at_end():
        extra = ts.peek()
        what = (f"tier {names[-1]!r} holds more items than its size says" if names and extra.kind == "num"
                else f"the TextGrid has more than the {n_tiers} tier(s) its size says")
        raise DataError(f"{what}: unexpected {extra.value!r} after the last item", path=path,
                        line=extra.line)
    if not interval:
        if tier is not None:
            raise DataError(f"no interval tier named {tier!r}; the tiers are {names}", path=path,
                            item=tier)
        raise DataError(f"no interval tier (tiers: {names})", path=path)
    phone_tiers = [t for t in interval if PHONE_TIER.search(t[0].strip())]
    speakers = {t[0].partition(" - ")[0].strip() for t in phone_tiers if " - " in t[0]}
    if tier is None and len(speakers) > 1:
        # Montreal Forced Aligner writes one "<speaker> - phones" tier per speaker: whose is meant?
        phone_tiers = [t for t in phone_tiers if " - " in t[0]]
        shown = ", ".join(repr(t[0]) for t in phone_tiers)
        raise DataError(f"{len(phone_tiers)} phone tiers ({shown}; one per speaker, as Montreal Forced Aligner "
                        f"writes them): say which to read with --tier {phone_tiers[0][0]!r} (coartic inspect, animate; "
                        "tier= in Python); a fit spec reads the tier of one speaker, so keep only that speaker's "
                        "tiers in the TextGrid it is given", path=path, item=phone_tiers[0][0])
    pick = phone_tiers[0] if phone_tiers else interval[0]
    name, labels, starts, ends, lines = pick
    if not any(lab.strip() for lab in labels):
        held = f"{len(labels)} empty interval(s)" if labels else "no interval"
        raise DataError(f"tier {name!r} holds no label ({held}): nothing to read; "
                        f"align the recording first, or name the tier with the phones (tiers: {names})",
                        path=path, item=name)
    return Segments(tuple(labels), np.array(starts), np.array(ends), path, tuple(lines), name,
                    tuple(names))


_INTEGER = re.compile(r"[-+]?\d+")
# An integer time this large is HTK's 100 ns units (1 ms), not seconds (2.8 hours).
HTK_EVIDENCE = 10_000


# --- HTK and Festival/xlabel .lab ---------------------------------------------------------------


def parse_lab(text: str, path: Path) -> Segments:
    """HTK (`start end label`, integers in 100 ns units), the same in seconds (MOCHA-TIMIT: any
    time with a decimal point), or, if a lone `#` line ends a header, xlabel."""
    lines = text.splitlines()
    hash_line = next((i for i, s in enumerate(lines) if s.strip() == "#"), None)
    if hash_line is not None:
        return _parse_xlabel(lines, hash_line, path)
    labels: list[str] = []
    starts: list[float] = []
    ends: list[float] = []
    where: list[int | None] = []
    integers = True
    htk_line: int | None = None
    seconds_line: int | None = None
    for no, raw in enumerate(lines, start=1):
        s = raw.strip()
        if not s or s == ".":  # "." ends an utterance in an MLF
            continue
        if s.startswith(('"', "#!MLF!#")):
            raise DataError("this is an HTK master label file (MLF); split it into one .lab per "
                            "utterance", path=path, line=no)
        fields = s.split()
        if len(fields) < 3:
            raise DataError(f"expected 'start end label' (HTK, 100 ns units), found {s!r}",
                            path=path, line=no)
        try:
            start, end = float(fields[0]), float(fields[1])
        except ValueError:
            raise DataError(f"expected times 'start end label' (HTK integers in 100 ns units, or "
                            f"seconds), found {fields[0]!r} {fields[1]!r}", path=path,
                            line=no) from None
        if all(_INTEGER.fullmatch(f) for f in fields[:2]):
            if end >= HTK_EVIDENCE and htk_line is None:
                htk_line = no
        else:
            integers = False
            seconds_line = seconds_line or no
        if htk_line is not None and seconds_line is not None:
            raise DataError(f"line {htk_line} has HTK times (integers, 100 ns units) and line "
                            f"{seconds_line} times in seconds: HTK times must be integers on "
                            "every line", path=path, line=max(htk_line, seconds_line))
        labels.append(fields[2])
        starts.append(start)
        ends.append(end)
        where.append(no)
    if not labels:
        raise DataError("no labels found", path=path)
    # HTK writes integers (100 ns); MOCHA-TIMIT and others write seconds ("0.3500 0.4200 dh")
    per_second = HTK_UNITS_PER_SECOND if integers else 1.0  # divided: 4262000 / 1e7 is 0.4262 exactly
    return Segments(tuple(labels), np.array(starts) / per_second, np.array(ends) / per_second, path,
                    tuple(where))


def parse_timit(text: str, path: Path, rate: float = TIMIT_SAMPLE_RATE) -> Segments:
    """TIMIT .phn/.wrd: `start_sample end_sample label`, samples of the 16 kHz audio."""
    labels: list[str] = []
    starts: list[float] = []
    ends: list[float] = []
    where: list[int | None] = []
    for no, raw in enumerate(text.splitlines(), start=1):
        fields = raw.split()
        if not fields:
            continue
        if len(fields) < 3 or not all(_INTEGER.fullmatch(f) for f in fields[:2]):
            raise DataError(f"expected 'start_sample end_sample label' (TIMIT, integer samples at "
                            f"{rate:g} Hz), found {raw.strip()!r}", path=path, line=no)
        labels.append(fields[2])
        starts.append(int(fields[0]) / rate)
        ends.append(int(fields[1]) / rate)
        where.append(no)
    if not labels:
        raise DataError("no labels found", path=path)
    return Segments(tuple(labels), np.array(starts), np.array(ends), path, tuple(where))


def _parse_xlabel(lines: list[str], hash_line: int, path: Path) -> Segments:
    # Festival/xlabel: each line is `end_time colour label`; a segment starts where the
    # previous one ended, the first at 0. A first entry at time 0 (EMU's `H#`) marks the start
    # of the utterance, not a segment.
    labels: list[str] = []
    starts: list[float] = []
    ends: list[float] = []
    where: list[int | None] = []
    previous = 0.0
    for no in range(hash_line + 2, len(lines) + 1):
        s = lines[no - 1].strip()
        if not s:
            continue
        fields = s.split(None, 2)
        try:
            end = float(fields[0])
        except ValueError:
            raise DataError(f"expected 'end_time colour label' (xlabel), found {s!r}", path=path,
                            line=no) from None
        if len(fields) < 3:
            # a pause is written as a label (e.g. "pau", "#"); an absent one is a broken line
            raise DataError(f"expected 'end_time colour label' (xlabel), found {s!r}: no label",
                            path=path, line=no)
        label = fields[2].strip()
        if not labels and end == 0.0:
            continue
        labels.append(label)
        starts.append(previous)
        ends.append(end)
        where.append(no)
        previous = end
    if not labels:
        raise DataError("no labels after the '#' header line", path=path)
    return Segments(tuple(labels), np.array(starts), np.array(ends), path, tuple(where))


# --- plain TSV ------------------------------------------------------------------------------------


def parse_tsv(text: str, path: Path) -> Segments:
    """`start end label` in seconds, tab- (or else whitespace-) separated, optional header line.

    A header is a first line whose first two fields do not start like numbers ("start end label",
    "t0 t1 text"): a first line with a malformed number ("0.0x") is an error, not a header. Every line must have a
    label column (with tabs, an empty cell is an empty label, i.e. a pause, as Praat writes it)."""
    labels: list[str] = []
    starts: list[float] = []
    ends: list[float] = []
    where: list[int | None] = []
    for no, raw in enumerate(text.splitlines(), start=1):
        if not raw.strip() or raw.lstrip().startswith("#"):
            continue
        fields = raw.split("\t") if "\t" in raw else raw.split(None, 2)
        fields = [f.strip() for f in fields]
        if len(fields) < 2:
            raise DataError(f"expected 'start end label', found {raw.strip()!r}", path=path, line=no)
        try:
            start, end = float(fields[0]), float(fields[1])
        except ValueError:
            # a header's first two fields are words ("start", "t0"); "0.0x" is a broken number
            header = not any(f and (f[0].isdigit() or f[0] in "+-.") for f in fields[:2])
            if header and not labels and not where:  # a header line
                where.append(None)
                continue
            raise DataError(f"expected times in seconds, found {fields[0]!r} {fields[1]!r}",
                            path=path, line=no) from None
        if len(fields) < 3:
            raise DataError(f"no label after the times {fields[0]} {fields[1]} (write the pause "
                            "label, e.g. '#' or 'sil', for a pause)", path=path, line=no)
        labels.append(fields[2])
        starts.append(start)
        ends.append(end)
        where.append(no)
    lines = tuple(w for w in where if w is not None)
    if not labels:
        raise DataError("no labels found (expected lines 'start end label')", path=path)
    return Segments(tuple(labels), np.array(starts), np.array(ends), path, lines)


def write_tsv(segments: Segments, path: str | PathLike[str]) -> None:
    """Write `start end label` with a header; times with repr so they read back exactly."""
    with open(path, "w", encoding="utf-8") as f:
        f.write("start\tend\tlabel\n")
        for lab, s, e in zip(segments.labels, segments.starts, segments.ends):
            f.write(f"{float(s)!r}\t{float(e)!r}\t{lab}\n")
