"""From a corpus' phone labels to the model's phonemes.

A map is a TSV file (`corpus_label<TAB>phoneme[<TAB>why]`, `#` starts a comment line), a JSON
object, or a dict. Two special values: `=` keeps the corpus label as a phoneme of its own, and
the key `*` with value `=` keeps every label the map does not list. Pause labels (`sil`, `pau`,
`_`, `&p:`, `<p:>`, empty, ...) become the pause phoneme `#` unless the map says otherwise.
A label that the map neither lists nor keeps is an error naming the label, its file and line.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import resources
from os import PathLike
from pathlib import Path

from coartic.io.errors import DataError
from coartic.io.labels import Segments

PAUSE = "#"
KEEP = "="
PAUSE_LABELS = frozenset(
    {"", "#", "sil", "SIL", "pau", "PAU", "_", "&p:", "<p:>", "<sil>", "sp", "h#", "silence"}
)
MODEL_VOWELS = ("i", "e", "E", "a", "O", "o", "u")
MODEL_CONSONANTS = ("p", "b", "m", "f", "v", "t", "d", "n", "l", "r", "s", "z", "ts", "dz",
                    "tS", "dZ", "S", "k", "g", "J", "L", "j", "w")
MODEL_PHONEMES = (PAUSE, *MODEL_VOWELS, *MODEL_CONSONANTS)
BUILTIN = ("model", "german_sampa")


@dataclass(frozen=True)
class LabelMap:
    """Corpus label → model phoneme (KEEP keeps the label itself)."""

    mapping: Mapping[str, str]
    keep_unmapped: bool = False
    source: str = "<dict>"
    lines: Mapping[str, int] = field(default_factory=dict)

    @classmethod
    def model(cls) -> LabelMap:
        """Labels that already are model phonemes (the synthetic session); anything else is an error."""
        return cls({p: p for p in MODEL_PHONEMES}, source="builtin map 'model'")

    @classmethod
    def builtin(cls, name: str) -> LabelMap:
        if name == "model":
            return cls.model()
        if name not in BUILTIN:
            raise DataError(f"no built-in label map {name!r}; built-in maps: {list(BUILTIN)}")
        res = resources.files("coartic.io").joinpath("labelmaps", f"{name}.tsv")
        return cls._parse_tsv(res.read_text(encoding="utf-8"), f"builtin map {name!r} ({name}.tsv)")

    @classmethod
    def from_dict(cls, d: Mapping[str, str], source: str = "<dict>") -> LabelMap:
        mapping: dict[str, str] = {}
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
            mapping[k] = v
        return cls(mapping, keep, source)

    @classmethod
    def from_file(cls, path: str | PathLike[str]) -> LabelMap:
        p = Path(path)
        try:
            text = p.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as e:
            raise DataError(f"cannot read the label map: {e}", path=p) from None
        if p.suffix.lower() == ".json":
            try:
                d = json.loads(text)
            except json.JSONDecodeError as e:
                raise DataError(f"not valid JSON: {e.msg}", path=p, line=e.lineno) from None
            if not isinstance(d, dict):
                raise DataError("a JSON label map must be one object {label: phoneme}", path=p)
            return cls.from_dict(d, str(p))
        return cls._parse_tsv(text, str(p))

    @classmethod
    def _parse_tsv(cls, text: str, source: str) -> LabelMap:
        mapping: dict[str, str] = {}
        lines: dict[str, int] = {}
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
            else:
                mapping[label] = phoneme
            lines[label] = no
        return cls(mapping, keep, source, lines)

    def map_label(self, label: str) -> str | None:
        """The model phoneme for `label`, or None when the map has no answer."""
        if label in self.mapping:
            target = self.mapping[label]
            return label if target == KEEP else target
        if label in PAUSE_LABELS:
            return PAUSE
        if self.keep_unmapped:
            return label
        return None

    def apply(self, segments: Segments) -> Segments:
        out: list[str] = []
        for i, label in enumerate(segments.labels):
            phoneme = self.map_label(label)
            if phoneme is None:
                raise DataError(
                    f"phone {label!r} (segment {i + 1}) has no mapping in {self.source}; add a "
                    f"line '{label}<TAB>phoneme' (or '{label}<TAB>=' to keep it as a phoneme of "
                    "its own) to the label map",
                    path=segments.source, line=segments.lines[i], item=label)
            out.append(phoneme)
        return segments.with_labels(out)


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
