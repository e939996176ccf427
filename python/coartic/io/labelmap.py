"""From a corpus' phone labels to the model's phonemes.

A map is a TSV file (`corpus_label<TAB>phoneme[<TAB>why]`, `#` starts a comment line), a JSON
object, or a dict. Two special values: `=` keeps the corpus label as a phoneme of its own, and
the key `*` with value `=` keeps every label the map does not list. A key `re:<regex>` is a
pattern: it maps every label the regex matches in full (Python `re.fullmatch`; `(?i)` at its start
ignores case); labels listed literally come first, then the patterns in the map's order. Pause
labels (`sil`, `pau`, `_`, `&p:`, `<p:>`, empty, ...) become the pause phoneme `#` unless the map
says otherwise. A label that the map neither lists nor keeps is an error naming the label, its file
and line.

Phonetic-class fallbacks (`fallback:<phoneme>` → the phonemes that stand in for it when a table
lacks it): every map but `model` and `identity` has those of labelmaps/fallbacks.tsv; a map's own
`fallback:` lines replace one phoneme's list, and the line `fallback:*<TAB>none` drops the built-in
ones (the map then has only its own).

A fitted table records the map it was fitted with (`LabelMap.to_record`, in the table's metadata
under `label_map`); `LabelMap.recorded(table)` gives it back, so that whoever evaluates the table on
corpus labels maps them the same way.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from importlib import resources
from os import PathLike
from pathlib import Path
from typing import TYPE_CHECKING, Any

from coartic.io.errors import DataError, parse_json
from coartic.textfile import TextDecodeError, read_text
from coartic.io.labels import Segments
from coartic.table import PAUSE

if TYPE_CHECKING:
    from coartic.table import ParameterTable

KEEP = "="
PAUSE_LABELS = frozenset(
    {"", "#", "sil", "SIL", "pau", "PAU", "_", "&p:", "<p:>", "<sil>", "sp", "h#", "silence"}
)
MODEL_VOWELS = ("i", "e", "E", "a", "O", "o", "u")
MODEL_CONSONANTS = ("p", "b", "m", "f", "v", "t", "d", "n", "l", "r", "s", "z", "ts", "dz",
                    "tS", "dZ", "S", "k", "g", "J", "L", "j", "w")
MODEL_PHONEMES = (PAUSE, *MODEL_VOWELS, *MODEL_CONSONANTS)
BUILTIN = ("model", "german_sampa", "english_arpabet", "mocha", "timit", "ipa")
# The IPA phones of espeak-ng and of the Montreal Forced Aligner's IPA models (english_mfa,
# german_mfa, ...) -> model phonemes: also the phone map of alignment by synthesis (coartic.align)
IPA_TABLE = "phones_ipa.tsv"
# marks an IPA phone may start with (stress); length, aspiration, palatalisation, syllabicity and
# the like follow the phone and are left out, as is a diphthong's second part
IPA_STRESS = "ˈˌ"
PATTERN_PREFIX = "re:"
# `fallback:<phoneme>` → comma-separated phonemes that stand in for it when a table lacks it
FALLBACK_PREFIX = "fallback:"
CLASS_FALLBACKS = "fallbacks"  # labelmaps/fallbacks.tsv: every map but 'model' and identity maps has them
# `fallback:*<TAB>none`: this map's own fallbacks only, without the built-in phonetic classes
NO_CLASS_FALLBACKS = ("*", "none")
# The key of the table metadata that holds the label map a table was fitted with.
RECORD_KEY = "label_map"


@dataclass(frozen=True)
class LabelMap:
    """Corpus label → model phoneme (KEEP keeps the label itself)."""

    mapping: Mapping[str, str]
    keep_unmapped: bool = False
    source: str = field(default="<dict>", compare=False)  # where it came from, for messages
    lines: Mapping[str, int] = field(default_factory=dict, compare=False)
    # (regex, phoneme) in the map's order, tried after the literal labels; keys keep the "re:" text
    patterns: tuple[tuple[str, str], ...] = ()
    name: str | None = None  # the built-in map's name
    # model phoneme → the phonemes that stand in for it, in order, when a table lacks it
    fallbacks: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    _compiled: tuple[tuple[re.Pattern[str], str], ...] = field(
        init=False, repr=False, compare=False, default=())

    def __post_init__(self) -> None:
        compiled = []
        for key, phoneme in self.patterns:
            try:
                compiled.append((re.compile(key[len(PATTERN_PREFIX):]), phoneme))
            except re.error as e:
                line = self.lines.get(key)
                where = f", line {line}" if line is not None else ""
                raise DataError(f"{self.source}{where}: pattern {key!r} is not a valid regular "
                                f"expression: {e}", line=line, item=key) from None
        object.__setattr__(self, "_compiled", tuple(compiled))

    @classmethod
    def model(cls) -> LabelMap:
        """Labels that already are model phonemes (the synthetic session); anything else is an error."""
        return cls({p: p for p in MODEL_PHONEMES}, source="builtin map 'model'", name="model")

    @classmethod
    def builtin(cls, name: str) -> LabelMap:
        if name == "model":
            return cls.model()
        if name == "ipa":
            return cls.ipa()
        if name not in BUILTIN:
            raise DataError(f"no built-in label map {name!r}; built-in maps: {list(BUILTIN)}")
        res = resources.files("coartic.io").joinpath("labelmaps", f"{name}.tsv")
        m = cls._parse_tsv(res.read_text(encoding="utf-8"), f"builtin map {name!r} ({name}.tsv)")
        return cls(m.mapping, m.keep_unmapped, m.source, m.lines, m.patterns, name, m.fallbacks)

    @classmethod
    def ipa(cls) -> LabelMap:
        """IPA phones (MFA's IPA models, espeak-ng) → model phonemes, from labelmaps/phones_ipa.tsv:
        a label maps as the longest phone of the table it starts with (after a stress mark), so that
        length, aspiration and other marks after it, and a diphthong's second part, are left out
        ([tʃʰ] → tS, [aj] → a, [iː] → i, [ɫ̩] → l); MFA's pause labels and its spoken noise `spn`
        are the pause."""
        res = resources.files("coartic.io").joinpath("labelmaps", IPA_TABLE)
        source = f"builtin map 'ipa' ({IPA_TABLE})"
        rows = []
        for no, raw in enumerate(res.read_text(encoding="utf-8").splitlines(), start=1):
            if no > 1 and raw.strip() and not raw.startswith("#"):  # line 1: the header
                phone, phoneme = raw.split("\t")[:2]
                rows.append((phone, phoneme))
        entries = {label: PAUSE for label in PAUSE_LABELS} | {"spn": PAUSE}
        for phone, phoneme in sorted(rows, key=lambda r: -len(r[0])):  # [tʃ] before [t]
            entries[f"{PATTERN_PREFIX}[{IPA_STRESS}]?{re.escape(phone)}.*"] = phoneme
        m = cls.from_dict(entries, source)
        return cls(m.mapping, m.keep_unmapped, m.source, m.lines, m.patterns, "ipa", m.fallbacks)

    @classmethod
    def from_dict(cls, d: Mapping[str, str], source: str = "<dict>") -> LabelMap:
        mapping: dict[str, str] = {}
        patterns: list[tuple[str, str]] = []
        fallbacks: dict[str, tuple[str, ...]] = {}
        keep = False
        for k, v in d.items():
            if not isinstance(k, str) or not isinstance(v, str):
                raise DataError(f"{source}: label map entries must be strings, found {k!r}: {v!r}")
            if k == "*":
                if v != KEEP:
                    raise DataError(f"{source}: '*' may only map to '=' (keep unmapped labels), "
                                    f"found {v!r}", item="*")
                keep = True
                continue
            if k.startswith(PATTERN_PREFIX):
                patterns.append((k, v))
            elif k.startswith(FALLBACK_PREFIX):
                fallbacks[_fallback_key(k, source, None)] = _fallback_list(v, k, source, None)
            else:
                mapping[k] = v
        return cls(mapping, keep, source, patterns=tuple(patterns), fallbacks=_with_classes(fallbacks, source, None))

    @classmethod
    def from_file(cls, path: str | PathLike[str]) -> LabelMap:
        p = Path(path)
        try:
            text = read_text(p, "label map")
        except OSError as e:
            raise DataError(f"cannot read the label map: {e.strerror or e}", path=p) from None
        except TextDecodeError as e:
            raise DataError(e.detail, path=p) from None
        if p.suffix.lower() == ".json":
            d = parse_json(text, p)
            if not isinstance(d, dict):
                raise DataError("a JSON label map must be one object {label: phoneme}", path=p)
            return cls.from_dict(d, str(p))
        return cls._parse_tsv(text, str(p))

    @classmethod
    def _parse_tsv(cls, text: str, source: str) -> LabelMap:
        mapping: dict[str, str] = {}
        lines: dict[str, int] = {}
        patterns: list[tuple[str, str]] = []
        fallbacks: dict[str, tuple[str, ...]] = {}
        keep = False
        for no, raw in enumerate(text.splitlines(), start=1):
            if not raw.strip() or raw.startswith("#"):
                continue
            fields = raw.split("\t")
            if len(fields) < 2 or not fields[1].strip():
                raise DataError(f"{source}, line {no}: expected 'label<TAB>phoneme', found {raw!r}",
                                line=no)
            label, phoneme = fields[0].strip(), fields[1].strip()
            if label in lines:
                raise DataError(f"{source}, line {no}: label {label!r} is mapped twice (first on "
                                f"line {lines[label]})", line=no, item=label)
            if label == "*":
                if phoneme != KEEP:
                    raise DataError(f"{source}, line {no}: '*' may only map to '='", line=no)
                keep = True
            elif label.startswith(PATTERN_PREFIX):
                patterns.append((label, phoneme))
            elif label.startswith(FALLBACK_PREFIX):
                fallbacks[_fallback_key(label, source, no)] = _fallback_list(phoneme, label, source, no)
            else:
                mapping[label] = phoneme
            lines[label] = no
        return cls(mapping, keep, source, lines, tuple(patterns),
                   fallbacks=_with_classes(fallbacks, source, lines.get(FALLBACK_PREFIX + "*")))

    # ------------------------------------------------------------- the table's record

    def to_record(self) -> dict[str, Any]:
        """What a fitted table stores (metadata["label_map"]): the whole map, not just its name
        or path, so that the table maps labels the same way after the file or built-in changed."""
        entries = ([[k, v] for k, v in self.mapping.items()] + [[k, v] for k, v in self.patterns]
                   + [[FALLBACK_PREFIX + k, ",".join(v)] for k, v in self.fallbacks.items()])
        if self.fallbacks != {**_class_fallbacks(), **self.fallbacks}:
            # a map without the built-in classes: read back without them too (from_dict adds them)
            entries.append([FALLBACK_PREFIX + NO_CLASS_FALLBACKS[0], NO_CLASS_FALLBACKS[1]])
        if self.keep_unmapped:
            entries.append(["*", KEEP])
        rec: dict[str, Any] = {"source": self.source, "entries": entries}
        if self.name is not None:
            rec["name"] = self.name
        return rec

    @classmethod
    def from_record(cls, record: Any, source: str = "<table>") -> LabelMap:
        """The map `to_record` wrote; a DataError naming `source` if the record is malformed."""
        where = f"{source}: metadata.{RECORD_KEY}"
        if not isinstance(record, Mapping) or not isinstance(record.get("entries"), list):
            raise DataError(f"{where} must be an object with a list 'entries' of [label, phoneme] "
                            f"pairs, found {str(record)[:80]!r}", item=RECORD_KEY)
        pairs: dict[str, str] = {}
        for e in record["entries"]:
            if (not isinstance(e, list) or len(e) != 2
                    or not all(isinstance(x, str) for x in e)):
                raise DataError(f"{where}: entry {str(e)[:80]} is not a [label, phoneme] pair",
                                item=RECORD_KEY)
            if e[0] in pairs:
                raise DataError(f"{where}: label {e[0]!r} is mapped twice", item=e[0])
            pairs[e[0]] = e[1]
        name = record.get("name")
        if name == "model" and not any(k.startswith(FALLBACK_PREFIX) for k in pairs):
            # the model map has no fallbacks (tables written before maps recorded 'fallback:*')
            pairs[FALLBACK_PREFIX + NO_CLASS_FALLBACKS[0]] = NO_CLASS_FALLBACKS[1]
        m = cls.from_dict(pairs, f"the label map recorded in {source} "
                                 f"({record.get('source', 'no source')})")
        return cls(m.mapping, m.keep_unmapped, m.source, m.lines, m.patterns,
                   name if isinstance(name, str) else None, m.fallbacks)

    def record_in(self, table: ParameterTable) -> None:
        """Store this map in the table's metadata (what `coartic fit` does with its spec's map)."""
        table.metadata[RECORD_KEY] = self.to_record()

    @classmethod
    def recorded(cls, table: ParameterTable) -> LabelMap | None:
        """The label map `table` was fitted with, or None for a table that records none (its
        labels are then its phonemes; `LabelMap.model()` is the map such tables were fitted with).
        A malformed record is the table's TableError."""
        rec = table.metadata.get(RECORD_KEY)
        if rec is None:
            return None
        from coartic.table import TableError

        try:
            return cls.from_record(rec, table.source)
        except DataError as e:  # a table's fault, reported as the table's error
            raise TableError(str(e)) from None

    @classmethod
    def identity(cls, phonemes: Sequence[str], source: str) -> LabelMap:
        """Each of `phonemes` stands for itself; anything else is an error."""
        return cls({p: p for p in phonemes}, source=source)

    def map_label(self, label: str) -> str | None:
        """The model phoneme for `label`, or None when the map has no answer."""
        if label in self.mapping:
            target = self.mapping[label]
            return label if target == KEEP else target
        for rx, target in self._compiled:
            if rx.fullmatch(label):
                return label if target == KEEP else target
        if label in PAUSE_LABELS:
            return PAUSE
        if self.keep_unmapped:
            return label
        return None

    def apply_labels(self, labels: Sequence[str], where: str = "") -> list[str]:
        """`labels` mapped, for lists without a file (a DataError naming the first unmapped one)."""
        out: list[str] = []
        for i, label in enumerate(labels):
            phoneme = self.map_label(label)
            if phoneme is None:
                raise DataError(f"{where}{': ' if where else ''}label {label!r} (segment {i + 1}) "
                                f"has no mapping in {self.source}", item=label)
            out.append(phoneme)
        return out

    def maps_all(self, labels: Sequence[str]) -> bool:
        """Whether every one of ``labels`` has a mapping (for suggesting a built-in map)."""
        return all(self.map_label(label) is not None for label in labels)

    def apply(self, segments: Segments) -> Segments:
        out: list[str] = []
        for i, label in enumerate(segments.labels):
            phoneme = self.map_label(label)
            if phoneme is None:
                fits = [n for n in BUILTIN if n != self.name and LabelMap.builtin(n).maps_all(segments.labels)]
                hint = (f"; the built-in map {' or '.join(fits)} maps every label of this file: --label-map "
                        f"{fits[0]} (label_map = \"{fits[0]}\" in a spec)" if fits else "")
                raise DataError(
                    f"phone {label!r} (segment {i + 1}{segments.tier_note()}) "
                    f"has no mapping in {self.source}{hint}; or add a "
                    f"line '{label}<TAB>phoneme' (or '{label}<TAB>=' to keep it as a phoneme of "
                    "its own) to the label map",
                    path=segments.source, line=segments.lines[i], item=label)
            out.append(phoneme)
        return segments.with_labels(out)


def _class_fallbacks() -> dict[str, tuple[str, ...]]:
    """labelmaps/fallbacks.tsv: the phonetic classes every map but `model` and identity maps extends."""
    res = resources.files("coartic.io").joinpath("labelmaps", f"{CLASS_FALLBACKS}.tsv")
    out: dict[str, tuple[str, ...]] = {}
    for no, raw in enumerate(res.read_text(encoding="utf-8").splitlines(), start=1):
        if raw.strip() and not raw.startswith("#"):
            key, value = raw.split("\t")[:2]
            out[_fallback_key(key, f"{CLASS_FALLBACKS}.tsv", no)] = _fallback_list(value, key, CLASS_FALLBACKS, no)
    return out


def _with_classes(own: dict[str, tuple[str, ...]], source: str, line: int | None) -> dict[str, tuple[str, ...]]:
    """A map's fallbacks: the built-in phonetic classes extended (and overridden) by its own
    `fallback:` lines, unless it says `fallback:*<TAB>none` (its own only)."""
    star = own.pop("*", None)
    if star is None:
        return {**_class_fallbacks(), **own}
    if star != NO_CLASS_FALLBACKS[1:]:
        where = f", line {line}" if line is not None else ""
        raise DataError(f"{source}{where}: 'fallback:*' may only say 'none' (no built-in phonetic-class "
                        f"fallbacks), found {','.join(star)!r}", line=line, item=FALLBACK_PREFIX + "*")
    return own


def _fallback_key(key: str, source: str, line: int | None) -> str:
    phoneme = key[len(FALLBACK_PREFIX):].strip()
    if not phoneme:
        where = f", line {line}" if line is not None else ""
        raise DataError(f"{source}{where}: {key!r} names no phoneme (write 'fallback:<phoneme>')",
                        line=line, item=key)
    return phoneme


def _fallback_list(value: str, key: str, source: str, line: int | None) -> tuple[str, ...]:
    out = tuple(v.strip() for v in value.split(","))
    if not all(out):
        where = f", line {line}" if line is not None else ""
        raise DataError(f"{source}{where}: {key} {value!r}: expected phonemes separated by commas",
                        line=line, item=key)
    return out


def resolve_label_map(spec: LabelMap | Mapping[str, str] | str | PathLike[str] | None) -> LabelMap:
    """None → the model phone set; a built-in name; a TSV/JSON file; a dict; or a LabelMap."""
    if spec is None:
        return LabelMap.model()
    if isinstance(spec, LabelMap):
        return spec
    if isinstance(spec, Mapping):
        return LabelMap.from_dict(spec)
    if isinstance(spec, str) and spec in BUILTIN:
        return LabelMap.builtin(spec)
    p = Path(spec)
    if not p.exists():
        raise DataError(f"label map {str(spec)!r} is neither a file nor a built-in map "
                        f"({list(BUILTIN)})")
    return LabelMap.from_file(p)
