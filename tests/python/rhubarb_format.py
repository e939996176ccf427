"""A reader of Rhubarb Lip Sync's output files, written from its README ("Output formats", "Moho and
OpenToonz", the options --extendedShapes, --datFrameRate, --datUsePrestonBlair) and nothing of
coartic's: what a program that consumes Rhubarb's files may rely on. Every rule it checks raises
`RhubarbFormatError` naming the line or cue."""

from __future__ import annotations

import json
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass

SHAPES = set("ABCDEFGHX")
PRESTON_BLAIR = {"MBP": "A", "etc": "B", "E": "C", "AI": "D", "O": "E", "U": "F", "FV": "G", "L": "H", "rest": "X"}
# "timestamp (in seconds)" with two decimals: every example is 0.00-style, times are multiples of 0.01 s
TIME = re.compile(r"\d+\.\d\d")


class RhubarbFormatError(ValueError):
    pass


@dataclass(frozen=True)
class Cue:
    start_cs: int
    end_cs: int
    value: str


def _cs(text: str, where: str) -> int:
    if not TIME.fullmatch(text):
        raise RhubarbFormatError(f"{where}: time {text!r} is not seconds with two decimals")
    whole, frac = text.split(".")
    return int(whole) * 100 + int(frac)


def _shape(value: str, where: str, extended: str) -> str:
    if value not in SHAPES:
        raise RhubarbFormatError(f"{where}: {value!r} is not a mouth shape A-H or X")
    if value in "GHX" and value not in extended:
        raise RhubarbFormatError(f"{where}: extended shape {value} was not chosen ({extended or 'none'})")
    return value


def _check_cues(cues: list[Cue], duration_cs: int) -> None:
    if not cues:
        raise RhubarbFormatError("no mouth cues")
    if cues[0].start_cs != 0:
        raise RhubarbFormatError("the first cue does not start at 0.00 (\"the very first output will always have the timestamp 0.00s\")")
    for k, (a, b) in enumerate(zip(cues, cues[1:])):
        if a.end_cs != b.start_cs:
            raise RhubarbFormatError(f"cue {k + 1} ends at {a.end_cs} cs, cue {k + 2} starts at {b.start_cs}: "
                                     "\"the end of each mouth cue is identical with the start of the following one\"")
    for k, c in enumerate(cues):
        if c.end_cs <= c.start_cs:
            raise RhubarbFormatError(f"cue {k + 1} is empty or runs backwards")
    if cues[-1].end_cs != duration_cs:
        raise RhubarbFormatError(f"the last cue ends at {cues[-1].end_cs} cs, not at the recording's end {duration_cs}")


def read_tsv(text: str, duration_cs: int, extended: str = "GHX") -> list[Cue]:
    """Lines 'timestamp<TAB>shape'; the last line is the end of the recording (truncated to 0.01 s)
    with a closed mouth: X, or A when X is not among the extended shapes."""
    lines = text.split("\n")
    if lines[-1] != "":
        raise RhubarbFormatError("the file does not end with a newline")
    rows = []
    for n, line in enumerate(lines[:-1], 1):
        parts = line.split("\t")
        if len(parts) != 2:
            raise RhubarbFormatError(f"line {n}: expected 'time<TAB>shape', got {line!r}")
        rows.append((_cs(parts[0], f"line {n}"), _shape(parts[1], f"line {n}", extended)))
    if len(rows) < 2:
        raise RhubarbFormatError("fewer than two lines: no cue before the final one")
    end, closed = rows[-1]
    if end != duration_cs:
        raise RhubarbFormatError(f"line {len(rows)}: the last timestamp {end} cs is not the recording's end {duration_cs}")
    if closed != ("X" if "X" in extended else "A"):
        raise RhubarbFormatError(f"line {len(rows)}: the last shape {closed} is not the closed mouth")
    cues = [Cue(s, e, v) for (s, v), (e, _) in zip(rows[:-1], rows[1:])]
    _check_cues(cues, duration_cs)
    return cues


def read_json(text: str, extended: str = "GHX") -> tuple[str, int, list[Cue]]:
    """{"metadata": {"soundFile", "duration"}, "mouthCues": [{"start", "end", "value"}]} → sound, duration, cues."""
    doc = json.loads(text)
    if set(doc) != {"metadata", "mouthCues"} or set(doc["metadata"]) != {"soundFile", "duration"}:
        raise RhubarbFormatError(f"keys {sorted(doc)} / {sorted(doc.get('metadata', {}))}: not Rhubarb's JSON")
    # the times are written with two decimals: read them from the text, not as floats
    times = re.findall(r'"(start|end|duration)": (\d+\.\d+)', text)
    duration = _cs([t for k, t in times if k == "duration"][0], "metadata.duration")
    raw = [t for k, t in times if k != "duration"]
    cues = []
    for k, cue in enumerate(doc["mouthCues"]):
        if set(cue) != {"start", "end", "value"}:
            raise RhubarbFormatError(f"mouthCues[{k}]: keys {sorted(cue)}")
        cues.append(Cue(_cs(raw[2 * k], f"mouthCues[{k}].start"), _cs(raw[2 * k + 1], f"mouthCues[{k}].end"),
                        _shape(cue["value"], f"mouthCues[{k}]", extended)))
    _check_cues(cues, duration)
    return str(doc["metadata"]["soundFile"]), duration, cues


def read_xml(text: str, extended: str = "GHX") -> tuple[str, int, list[Cue]]:
    """<rhubarbResult><metadata><soundFile/><duration/></metadata><mouthCues><mouthCue start end>shape."""
    if not text.startswith('<?xml version="1.0" encoding="utf-8"?>\n'):
        raise RhubarbFormatError("no XML declaration with utf-8")
    root = ET.fromstring(text.encode("utf-8"))
    if root.tag != "rhubarbResult" or [c.tag for c in root] != ["metadata", "mouthCues"]:
        raise RhubarbFormatError(f"root {root.tag} with {[c.tag for c in root]}: not Rhubarb's XML")
    meta = root.find("metadata")
    assert meta is not None
    sound, duration = meta.findtext("soundFile"), meta.findtext("duration")
    if sound is None or duration is None:
        raise RhubarbFormatError("metadata without soundFile or duration")
    cues = []
    for k, el in enumerate(root.iter("mouthCue")):
        cues.append(Cue(_cs(el.get("start", ""), f"mouthCue {k + 1} start"), _cs(el.get("end", ""), f"mouthCue {k + 1} end"),
                        _shape(el.text or "", f"mouthCue {k + 1}", extended)))
    d = _cs(duration, "metadata/duration")
    _check_cues(cues, d)
    return sound, d, cues


def read_dat(text: str, fps: float, extended: str = "GHX", preston_blair: bool = False) -> list[tuple[int, str]]:
    """Moho switch data: 'MohoSwitch1', then 'frame shape' lines, frames counted from 1 at
    --datFrameRate (24 to 100 fps), increasing; the last line the closed mouth. Shapes by their
    letters or, with --datUsePrestonBlair, Preston Blair's names."""
    if not 24 <= fps <= 100:
        raise RhubarbFormatError(f"DAT frame rate {fps} outside Rhubarb's 24-100")
    lines = text.split("\n")
    if lines[0] != "MohoSwitch1" or lines[-1] != "":
        raise RhubarbFormatError("not a Moho switch file (first line MohoSwitch1, a newline at the end)")
    rows: list[tuple[int, str]] = []
    for n, line in enumerate(lines[1:-1], 2):
        m = re.fullmatch(r"(\d+) (\S+)", line)
        if not m:
            raise RhubarbFormatError(f"line {n}: expected 'frame shape', got {line!r}")
        name = m.group(2)
        shape = PRESTON_BLAIR.get(name, "?") if preston_blair else name
        rows.append((int(m.group(1)), _shape(shape, f"line {n}", extended)))
    frames = [f for f, _ in rows]
    if not rows or frames[0] < 1 or any(b <= a for a, b in zip(frames, frames[1:])):
        raise RhubarbFormatError(f"frames {frames[:8]}...: not increasing from 1")
    if rows[-1][1] != ("X" if "X" in extended else "A"):
        raise RhubarbFormatError("the last line is not the closed mouth")
    return rows
