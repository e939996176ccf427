"""Load the utterances a fit spec names (manifest or file list) through ``coartic.io.load_trial``."""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from coartic.estimation.emotions import ASYMMETRY_META, corner_asymmetry
from coartic.model import Utterance, utterances_with_postures
from coartic.errors import SpecError
from coartic.fit.spec import FitSpec, synth_hint
from coartic.io import DataError, load_trial
from coartic.textfile import TextDecodeError, read_text


def manifest_rows(spec: FitSpec) -> list[dict[str, str | None]]:
    """The manifest's rows, kept by ``[corpus] select`` and ``limit``; paths made absolute."""
    c = spec.corpus_spec
    if c.manifest is None:
        labels: Sequence[Path | None] = c.labels or [None] * len(c.files)
        rows = [{c.file_column: str(f), "labels": None if lab is None else str(lab), "stimulus": f.stem}
                for f, lab in zip(c.files, labels)]
    else:
        if c.manifest.is_dir():
            raise SpecError.at(spec.path, "corpus.manifest", f"{c.manifest} is a directory: name the manifest "
                               f"file in it (e.g. {c.manifest / 'manifest.csv'})")
        if not c.manifest.is_file():
            raise SpecError.at(spec.path, "corpus.manifest", f"{c.manifest} does not exist{synth_hint(c.manifest)}")
        try:
            text = read_text(c.manifest, "manifest")
        except TextDecodeError as e:
            raise SpecError.at(spec.path, "corpus.manifest", f"{e}") from None
        with io.StringIO(text, newline="") as f:
            reader = csv.DictReader(f)
            read: list[dict[str, str]] = []
            lines = []
            for r in reader:
                # A short row leaves None in its last columns, a long one puts the excess under None:
                # either way the row cannot be read as the header says (line numbers as an editor's).
                if None in r or any(v is None for v in r.values()):
                    extra = r.pop(None, None) or []
                    n = sum(v is not None for v in r.values()) + len(extra)
                    raise SpecError(f"{c.manifest}, line {reader.line_num}: {n} cells, the header has "
                                    f"{len(reader.fieldnames or [])} ({', '.join(reader.fieldnames or [])})")
                read.append(r)
                lines.append(reader.line_num)
            cols = reader.fieldnames or []
        # A manifest without a labels column, or with an empty cell, means the data file's own labels.
        for need in (c.file_column,):
            if need not in cols:
                raise SpecError.at(spec.path, "corpus", f"manifest {c.manifest} has no column {need!r} "
                                   f"(columns: {', '.join(cols)})")
        for k in c.select:
            if k not in cols:
                raise SpecError.at(spec.path, "corpus.select", f"{k!r} is not a manifest column "
                                   f"(columns: {', '.join(cols)})")
        base = c.manifest.parent
        for line, r in zip(lines, read):
            if not r[c.file_column].strip():
                raise SpecError(f"{c.manifest}, line {line}: the {c.file_column!r} cell is empty")
        rows = [{**r, c.file_column: str(base / r[c.file_column]),
                 "labels": str(base / r["labels"]) if (r.get("labels") or "").strip() else None}
                for r in read]
    rows = [r for r in rows if all(r.get(k, "") in v for k, v in c.select.items())]
    if c.limit is not None:
        rows = rows[: c.limit]
    if not rows:
        raise SpecError.at(spec.path, "corpus", f"no trial left after select = {c.select}")
    return rows


def load_utterances(spec: FitSpec, rows: Sequence[Mapping[str, str | None]] | None = None,
                    progress: Callable[[int, int], None] | None = None, asymmetry: bool = False,
                    notes: list[str] | None = None) -> list[Utterance]:
    """One Utterance per trial with the spec's channels (gaps filled up to max_gap, longer ones
    masked), pauses given their posture (``with_spec_pauses``; each change named in ``notes``)."""
    rows = manifest_rows(spec) if rows is None else rows
    c = spec.corpus_spec
    utts = load_rows(rows, spec.channels, file_column=c.file_column, label_map=c.label_map, role_map=c.role_map,
                     max_gap=spec.gaps.max_gap, where=f"the corpus in {spec.path}", progress=progress,
                     asymmetry=spec.groups.emotions != "none")
    return with_spec_pauses(spec, utts, notes)


def with_spec_pauses(spec: FitSpec, utterances: Sequence[Utterance], notes: list[str] | None = None) -> list[Utterance]:
    """The utterances as the spec fits them: with ``[model] pauses = "postures"`` (the default)
    initial, final and medial pauses are three rows and short pauses in a closure join it
    (``coartic.pauses``; a note per change in ``notes``); with "one", as they are. Applying it twice
    changes nothing."""
    if spec.model.pauses != "postures":
        return list(utterances)
    out, said = utterances_with_postures(utterances)
    if notes is not None:
        notes += said
    return out


def load_rows(rows: Sequence[Mapping[str, str | None]], channels: Sequence[str], *, file_column: str = "file",
              label_map: Any = None, role_map: Any = None, max_gap: float = 0.05, where: str = "the recordings",
              progress: Callable[[int, int], None] | None = None, asymmetry: bool = False) -> list[Utterance]:
    """The trials of ``rows`` (data file in ``file_column``, label file in ``labels``, or None for
    an EMU bundle's own; other cells become ``meta``) as Utterances with ``channels``: the one
    loader of the fit, its validation and ``coartic score``. ``asymmetry``: each trial's mean corner
    asymmetries too (``coartic.estimation.emotions.corner_asymmetry``, in meta), for ``[model] emotions``."""
    out: list[Utterance] = []
    for i, r in enumerate(rows):
        path = Path(str(r[file_column]))
        try:
            trial = load_trial(path, labels=r.get("labels"), label_map=label_map, role_map=role_map)
            ch = trial.channels(list(channels), max_gap=max_gap)
        except DataError as e:
            raise DataError(f"{e} (trial {i + 1} of {where})") from None
        seg = trial.segments
        if seg is None:
            raise DataError(f"{path}: no labels (trial {i + 1} of {where}): the file carries none of its "
                            "own, give its label file")
        meta = {k: str(v) for k, v in r.items() if k not in (file_column, "labels") and v is not None}
        asym = corner_asymmetry(trial.markers, trial.marker_names) if asymmetry else None
        if asym is not None:
            meta |= {ASYMMETRY_META[k]: repr(v) for k, v in asym.items()}
        out.append(Utterance(
            name=meta.get("stimulus", path.stem) + (f"#{meta['repetition']}" if "repetition" in meta else "")
            + (f"@{meta['rate']}" if "rate" in meta else ""),
            labels=seg.labels, starts=np.asarray(seg.starts, dtype=np.float64),
            ends=np.asarray(seg.ends, dtype=np.float64), times=np.asarray(ch.times, dtype=np.float64),
            observed={c: np.asarray(ch[c], dtype=np.float64) for c in channels},
            valid={c: np.asarray(ch.valid[c], dtype=bool) for c in channels},
            meta={"file": str(path), **meta}))
        if progress is not None:
            progress(i + 1, len(rows))
    return out


def select(utterances: list[Utterance], **criteria: tuple[str, ...] | str) -> list[Utterance]:
    """Utterances whose meta matches every criterion (value or tuple of accepted values)."""
    def ok(u: Utterance) -> bool:
        return all(u.meta.get(k) in ((v,) if isinstance(v, str) else v) for k, v in criteria.items())
    return [u for u in utterances if ok(u)]


def group_of(u: Utterance, group: str, spec: FitSpec) -> str:
    """The value of ``[validate] group`` for an utterance: its manifest column, the sentence (or
    stimulus), or for "utterance" its file."""
    if group == "utterance":
        return u.meta.get("file") or u.name
    keys = ("sentence", "stimulus") if group == "sentence" else (group,)
    for k in keys:
        if k in u.meta:
            v = u.meta[k]
            return str(int(v)) if group == "repetition" and v.isdigit() else v
    raise SpecError.at(spec.path, "validate.group", f"{group!r}: the corpus has no {' or '.join(map(repr, keys))} "
                       "column (a manifest column), so its utterances cannot be grouped by it")
