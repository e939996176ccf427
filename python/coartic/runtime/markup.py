"""APML-like emotion markup: the text to say, with changes of emotion around its words.

LUCIA and Greta take their emotions from APML (Affective Presentation Markup Language, De Carolis,
Pelachaud, Poggi and Steedman 2004): a ``<performative>`` element around words, whose ``affect``
attribute names the expression. ``coartic speak --emotion-markup FILE`` reads the same shape::

    <apml>
      <performative affect="joy" intensity="0.6">Il babbo mangia</performative>
      la <performative affect="sadness">pappa.</performative>
    </apml>

The root element may have any name (``apml`` by convention); ``<performative>`` elements may nest
(the innermost with an ``affect`` wins) and may carry APML's other attributes (``type``, ``id``...),
which are kept out of the way; ``intensity`` (0-1.5, default 1) is coartic's. Words outside every
``affect`` are neutral. Every other element is refused, so a typo does not pass silently. The
markup is parsed with the standard library's XML parser (expat); a malformed file, an unknown
element or attribute, an emotion the table lacks or an intensity out of range is an
``EmotionError`` naming the file, line and column.

After synthesis the words are found in Festival's (``festival.FestivalUtterance.words``: aligned
by their spelling, lower-cased without punctuation, so that a number Festival reads as several
words still takes its emotion), and each run of words with one emotion becomes one span from its
first word's start to its last word's end (``coartic.emotions.EmotionSpan``): the same spans, ramps
and contacts as ``--emotion-spans``.
"""

from __future__ import annotations

import bisect
import difflib
import itertools
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence
from xml.parsers import expat

from coartic.emotions import MAX_INTENSITY, EmotionError, EmotionSpan, with_emotion_spans
from coartic.table import ParameterTable

ELEMENT = "performative"
ATTRIBUTES = ("affect", "intensity", "type", "id", "certainty", "belief-relation", "meaning")  # APML's + ours
_WORD = re.compile(r"\S+")
_PUNCT = re.compile(r"[^\w']+", re.UNICODE)


@dataclass(frozen=True)
class MarkedWord:
    """A word of the markup's text, the emotion around it (None: neutral) and its intensity."""

    word: str
    emotion: str | None
    intensity: float
    line: int  # where the word's element starts (for errors)
    column: int


@dataclass(frozen=True)
class Markup:
    source: str
    words: tuple[MarkedWord, ...]

    @property
    def text(self) -> str:
        """The text to say: the markup's words, tags removed."""
        return " ".join(w.word for w in self.words)

    def emotions(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(w.emotion for w in self.words if w.emotion is not None))


def parse_markup(text: str, source: str = "<markup>") -> Markup:
    """The words of an APML-like markup with the emotion each is said with (module docstring)."""
    parser = expat.ParserCreate()
    stack: list[tuple[str | None, float, int, int]] = []  # per open element: (emotion, intensity, line, col)
    chunks: list[tuple[str, str | None, float, int, int]] = []
    depth = 0

    def where() -> str:
        return f"{source}, line {parser.CurrentLineNumber}, column {parser.CurrentColumnNumber + 1}"

    def start(name: str, attrs: dict[str, str]) -> None:
        nonlocal depth
        depth += 1
        if depth == 1:  # the root: any name, no meaning of its own
            stack.append((None, 1.0, parser.CurrentLineNumber, parser.CurrentColumnNumber + 1))
            return
        if name != ELEMENT:
            raise EmotionError(f"{where()}: <{name}>: not an element of the emotion markup (give "
                               f"<{ELEMENT} affect=\"joy\">words</{ELEMENT}>)")
        unknown = [a for a in attrs if a not in ATTRIBUTES]
        if unknown:
            raise EmotionError(f"{where()}: <{name}> has unknown attribute(s) {', '.join(unknown)} "
                               f"(known: {', '.join(ATTRIBUTES)})")
        emotion, intensity = stack[-1][0], stack[-1][1]
        if "affect" in attrs:
            emotion = attrs["affect"].strip()
            if not emotion:
                raise EmotionError(f"{where()}: <{name} affect=\"\">: name an emotion")
            intensity = 1.0
        if "intensity" in attrs:
            if "affect" not in attrs:
                raise EmotionError(f"{where()}: <{name}> has an intensity but no affect")
            try:
                intensity = float(attrs["intensity"])
            except ValueError:
                intensity = math.nan
            if not (math.isfinite(intensity) and 0.0 <= intensity <= MAX_INTENSITY):
                raise EmotionError(f"{where()}: intensity={attrs['intensity']!r}: expected a number from 0 to "
                                   f"{MAX_INTENSITY:g}")
        stack.append((emotion, intensity, parser.CurrentLineNumber, parser.CurrentColumnNumber + 1))

    def end(name: str) -> None:
        nonlocal depth
        depth -= 1
        stack.pop()

    def data(s: str) -> None:
        if not stack:  # (expat refuses text outside the root itself)
            return
        emotion, intensity, line, col = stack[-1]
        chunks.append((s, emotion, intensity, line, col))

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    parser.CharacterDataHandler = data
    try:
        parser.Parse(text, True)
    except expat.ExpatError as e:
        raise EmotionError(f"{source}, line {e.lineno}, column {e.offset + 1}: not well-formed markup: "
                           f"{expat.ErrorString(e.code)} (the markup is XML: the words inside one root element, "
                           f"emotions as <{ELEMENT} affect=\"joy\">...</{ELEMENT}>; docs/EMOTIONS.md)") from None
    # a word split by a tag ("mang<performative ...>ia") is one word, said with its first letter's emotion
    full = "".join(c[0] for c in chunks)
    offsets = list(itertools.accumulate(len(c[0]) for c in chunks))
    words: list[MarkedWord] = []
    for m in _WORD.finditer(full):
        _, emotion, intensity, line, col = chunks[bisect.bisect_right(offsets, m.start())]
        words.append(MarkedWord(m.group(), emotion, intensity, line, col))
    if not words:
        raise EmotionError(f"{source}: the markup has no words to say")
    return Markup(source, tuple(words))


def read_markup(path: str | Path) -> Markup:
    """``parse_markup`` of a file (UTF-8)."""
    from coartic.textfile import read_text

    path = Path(path)
    return parse_markup(read_text(path, "emotion markup"), str(path))


def check_emotions(markup: Markup, table: ParameterTable) -> None:
    """Every emotion of the markup is one the table knows (else an error naming its line and column)."""
    from coartic.emotions import emotion_table, table_emotions

    known = table_emotions(table)
    for w in markup.words:
        if w.emotion is None:
            continue
        if not known:
            emotion_table(table, w.emotion)  # the error for a table without emotions
        if w.emotion not in known:
            raise EmotionError(f"{markup.source}, line {w.line}, column {w.column}: affect={w.emotion!r}: the table "
                               f"knows {', '.join(known)}")


def normalise(word: str) -> str:
    """A word as Festival names it: lower-cased, punctuation removed."""
    return _PUNCT.sub("", word.lower())


def word_times(words: Sequence[str], word_ids: Sequence[int], starts: Sequence[float],
               ends: Sequence[float]) -> list[tuple[str, float, float]]:
    """Festival's words in order, each with its first phone's start and its last phone's end."""
    out: dict[int, list[Any]] = {}
    for w, i, s, e in zip(words, word_ids, starts, ends):
        if i < 0:
            continue
        if i not in out:
            out[i] = [w, float(s), float(e)]
        else:
            out[i][2] = float(e)
    return [(str(w), s, e) for w, s, e in out.values()]


def spans_from_words(markup: Markup, timed: Sequence[tuple[str, float, float]]) -> list[EmotionSpan]:
    """The markup's emotions as time spans: its words aligned with the spoken ones by spelling
    (``difflib``; a run of markup words said as other words, a number read out, takes their time), each
    run of one emotion at one intensity one span from its first word's start to its last one's end."""
    mine = [normalise(w.word) for w in markup.words]
    theirs = [normalise(w) for w, _, _ in timed]
    span_of: list[tuple[float, float] | None] = [None] * len(mine)
    for op, i1, i2, j1, j2 in difflib.SequenceMatcher(None, mine, theirs, autojunk=False).get_opcodes():
        if op == "equal":
            for k in range(i2 - i1):
                span_of[i1 + k] = (timed[j1 + k][1], timed[j1 + k][2])
        elif op == "replace":
            for k in range(i1, i2):  # said otherwise: each takes the whole run's time
                span_of[k] = (timed[j1][1], timed[j2 - 1][2])
    return _merged(markup, span_of)


def _merged(markup: Markup, span_of: Sequence[tuple[float, float] | None]) -> list[EmotionSpan]:
    """Runs of consecutive timed words with one (emotion, intensity) as spans, in time order, none
    overlapping (a run that would start inside the previous one starts at its end)."""
    out: list[EmotionSpan] = []
    cur: list[Any] | None = None
    for w, t in zip(markup.words, span_of):
        if t is None:
            continue
        key = (w.emotion, w.intensity)
        if cur is not None and cur[0] == key:
            cur[2] = max(cur[2], t[1])
            continue
        if cur is not None and cur[0][0] is not None:
            out.append(EmotionSpan(cur[1], cur[2], cur[0][0], cur[0][1]))
        cur = [key, t[0], t[1]]
    if cur is not None and cur[0][0] is not None:
        out.append(EmotionSpan(cur[1], cur[2], cur[0][0], cur[0][1]))
    fixed: list[EmotionSpan] = []
    for s in out:
        start = max(s.start, fixed[-1].end) if fixed else s.start
        if s.end > start:
            fixed.append(EmotionSpan(start, s.end, s.emotion, s.intensity))
    return fixed


def with_markup(table: ParameterTable, markup: Markup) -> ParameterTable:
    """The table with the markup's words recorded (``metadata.expression.markup``): ``speak`` turns
    them into spans once Festival has said them (``apply_to_utterance``)."""
    import copy

    check_emotions(markup, table)
    out = copy.deepcopy(table)
    out.metadata = {**(out.metadata or {}), "expression": {"markup": {
        "source": markup.source,
        "words": [[w.word, w.emotion, w.intensity, w.line, w.column] for w in markup.words]}}}
    return out


def apply_to_utterance(table: ParameterTable, utt: Any) -> ParameterTable:
    """A table carrying a markup (``with_markup``) with its spans timed by Festival's utterance
    ``utt`` (``festival.FestivalUtterance``: words, word numbers, phone starts and ends); any other
    table as it is."""
    meta: Any = (table.metadata or {}).get("expression")
    if not isinstance(meta, dict) or "markup" not in meta:
        return table
    m = meta["markup"]
    markup = Markup(str(m["source"]), tuple(MarkedWord(str(w), e, float(i), int(ln), int(c))
                                            for w, e, i, ln, c in m["words"]))
    timed = word_times(utt.words, utt.word_ids, utt.starts, utt.ends)
    spans = spans_from_words(markup, timed)
    base = table
    base.metadata = {k: v for k, v in (table.metadata or {}).items() if k != "expression"}
    if not spans:  # every word neutral
        return base
    return with_emotion_spans(base, spans, markup.source)
