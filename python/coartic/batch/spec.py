"""The batch specification: one fit spec run over many speakers or sessions (``coartic batch``).

A batch spec is a small TOML file that names a fit spec (``fit/*.toml``: model, parameters, engine,
staging) and the corpus of many speakers or sessions, split into *groups*::

    name = "synthetic speakers"
    fit = "synthetic.toml"            # every unit fits with this spec; its [corpus] is replaced

    [corpus]
    manifest = "../build/speakers/manifest.csv"
    group_by = ["speaker"]            # one group per distinct value of these manifest columns
    # folders = ["../build/speakers/s*"]   # or: each matching folder's manifest.csv is one group
    # select = {rate = ["normal"]}    # rows kept (as in a fit spec), in every group

    [pooled]
    enabled = true                    # also one fit of every group's data together

    [posteriors]
    enabled = false                   # true: each group's posteriors too (the fit spec's [mcmc])

Every path is relative to the batch spec. The document is a typed schema (``BatchDocument``, its
sections ``BatchCorpus``, ``Pooled``, ``Posteriors``) checked by the fit spec's machinery
(``coartic.estimation.checks``): every error names the file and the key at fault, as the fit spec's
do (``coartic.fit.spec``). What needs the disk (the fit spec, the manifests, the folders) is checked
by ``load_batch_spec`` after it.
"""

from __future__ import annotations

import csv
import dataclasses
import glob
import hashlib
import io
import os
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Annotated, Any

import pydantic.dataclasses
from pydantic import BeforeValidator, ValidationError, model_validator
from pydantic_core import ArgsKwargs

from coartic.errors import SpecError
from coartic.estimation.checks import STRICT, Flag, _bad, _optional, schema_error
from coartic.fit.spec import CorpusSpec, FitSpec, OptionalPath, Select, load_spec, read_document, synth_hint
from coartic.textfile import TextDecodeError, read_text

# A group's name is a folder name in the output: plain characters only, and never one of ours.
GROUP_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*")
MAX_GROUPS = 100_000


@dataclass(frozen=True)
class Group:
    """One speaker or session: its name and the fit spec that loads exactly its trials."""

    name: str
    spec: FitSpec
    source: str  # how it was found (for messages): 'speaker = s01 in manifest.csv' or the folder


@dataclass(frozen=True)
class BatchSpec:
    path: Path  # the batch spec file
    name: str
    fit: FitSpec  # the fit spec as read (its corpus is the one it names, unused here)
    groups: tuple[Group, ...]
    channels: tuple[str, ...]
    pooled: bool
    pooled_spec: FitSpec  # the fit spec of the pooled fit (corpus: every group's)
    fingerprint: str  # what the results depend on: the spec files and manifests (sha256)
    mcmc: Any = None  # coartic.mcmc.run.McmcConfig from the fit spec's [mcmc], when posteriors are asked for
    posterior_channels: tuple[str, ...] = ()  # channels whose posteriors each group gets (none: no posteriors)

    @property
    def group_names(self) -> tuple[str, ...]:
        return tuple(g.name for g in self.groups)


def _err(path: Path, key: str, msg: str) -> SpecError:
    return SpecError.at(path, key, msg)


def _strings(v: Any) -> tuple[str, ...]:
    if isinstance(v, str):
        return (v,)
    if not isinstance(v, list) or not v or not all(isinstance(s, str) and s for s in v):
        raise _bad(f"expected a non-empty list of strings, got {v!r}")
    return tuple(v)


def _checked(check: Callable[[Any], bool], message: str) -> Callable[[Any], Any]:
    """A field check: ``v`` if ``check(v)``, else ``message`` (``{v!r}``: the value given)."""
    def run(v: Any) -> Any:
        if not check(v):
            raise _bad(message.format(v=v))
        return v
    return run


def _is_table(v: Any) -> bool:
    return isinstance(v, Mapping)


Strings = Annotated[tuple[str, ...] | None, BeforeValidator(_optional(_strings))]
_NO_FIT = "missing: the fit spec every unit uses, e.g. fit = 'synthetic.toml'"
_NO_CORPUS = "missing: give manifest and group_by, or folders"
_SWITCH = "expected a table with enabled = true/false, got {v!r}"


@pydantic.dataclasses.dataclass(frozen=True, config=STRICT)
class BatchCorpus:
    """``[corpus]``: one manifest split into groups by its ``group_by`` columns, or one group per
    folder (``folders`` patterns, each folder's ``manifest_name``); ``select`` keeps rows in every
    group. Paths as written (relative to the batch spec)."""

    manifest: OptionalPath = None
    group_by: Strings = None
    folders: Strings = None
    manifest_name: Annotated[str | None, BeforeValidator(_optional(_checked(
        lambda v: isinstance(v, str) and bool(v) and "/" not in v, "expected a file name, got {v!r}")))] = None
    select: Select = field(default_factory=dict)

    @model_validator(mode="after")
    def _one_source(self) -> BatchCorpus:
        if (self.manifest is None) == (self.folders is None):
            raise _bad("give either manifest (with group_by) or folders, not both and not neither")
        if self.manifest is not None and self.manifest_name is not None:
            raise _bad("only with folders", ("manifest_name",))
        if self.manifest is not None and self.group_by is None:
            raise _bad("missing: the manifest column(s) naming the speaker or session", ("group_by",))
        if self.folders is not None and self.group_by is not None:
            raise _bad("only with manifest (with folders, each folder is a group)", ("group_by",))
        return self


@pydantic.dataclasses.dataclass(frozen=True, config=STRICT)
class Pooled:
    """``[pooled]``: also one fit of every group's data together."""

    enabled: Flag = True


@pydantic.dataclasses.dataclass(frozen=True, config=STRICT)
class Posteriors:
    """``[posteriors]``: each group's posteriors too (the fit spec's ``[mcmc]``)."""

    enabled: Flag = False


@pydantic.dataclasses.dataclass(frozen=True, config=STRICT)
class BatchDocument:
    """A batch spec's TOML document, section by section (``fit`` as written: relative to the file)."""

    fit: Annotated[str | None, BeforeValidator(_checked(lambda v: isinstance(v, str) and bool(v), _NO_FIT))] = None
    name: Annotated[str | None, BeforeValidator(_checked(lambda v: isinstance(v, str),
                                                         "expected a string, got {v!r}"))] = None
    channels: Strings = None  # a subset of the fit spec's (None: all of them)
    corpus: Annotated[BatchCorpus | None, BeforeValidator(_checked(_is_table, _NO_CORPUS))] = None
    pooled: Annotated[Pooled, BeforeValidator(_checked(_is_table, _SWITCH))] = field(default_factory=Pooled)
    posteriors: Annotated[Posteriors, BeforeValidator(_checked(_is_table, _SWITCH))] = field(
        default_factory=Posteriors)

    @model_validator(mode="after")
    def _required(self) -> BatchDocument:
        if self.fit is None:
            raise _bad(_NO_FIT, ("fit",))
        if self.corpus is None:
            raise _bad(_NO_CORPUS, ("corpus",))
        return self


_SECTIONS: dict[str, type] = {"": BatchDocument, "corpus": BatchCorpus, "pooled": Pooled, "posteriors": Posteriors}


def _keys(section: str) -> list[str] | None:
    """The keys a section of the document may have ("": the top level)."""
    return [f.name for f in dataclasses.fields(_SECTIONS[section])] if section in _SECTIONS else None


def parse_document(raw: Mapping[str, Any], path: Path) -> BatchDocument:
    """The checked document of a batch spec; every problem named ``file: [key] message``."""
    try:
        doc: BatchDocument = BatchDocument.__pydantic_validator__.validate_python(  # type: ignore[attr-defined]
            ArgsKwargs((), dict(raw)))
    except ValidationError as e:
        raise schema_error(e, path, (), lambda loc: ".".join(str(p) for p in loc) or "top level",
                           lambda loc: _keys(".".join(map(str, loc))),
                           "BatchDocument") from None
    return doc


def _sha(path: Path, key: str, spec_path: Path) -> str:
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError as e:
        raise _err(spec_path, key, f"{path}: cannot read: {e.strerror}") from None


def _manifest_groups(manifest: Path, columns: tuple[str, ...], select: dict[str, tuple[str, ...]],
                     path: Path) -> list[tuple[str, tuple[str, ...]]]:
    """(group name, values of ``columns``) for every distinct combination, in order of appearance."""
    if manifest.is_dir():
        raise _err(path, "corpus.manifest", f"{manifest} is a directory: name the manifest file in it (e.g. "
                   f"{manifest / 'manifest.csv'}), or give folders = [...] for one group per folder")
    if not manifest.is_file():
        raise _err(path, "corpus.manifest", f"{manifest} does not exist{synth_hint(manifest)}")
    try:
        reader = csv.DictReader(io.StringIO(read_text(manifest, "manifest"), newline=""))
        rows = list(reader)
        cols = reader.fieldnames or []
    except TextDecodeError as e:
        raise _err(path, "corpus.manifest", str(e)) from None
    except (OSError, csv.Error) as e:
        raise _err(path, "corpus.manifest", f"{manifest}: cannot read: {e}") from None
    for c in (*columns, *select):
        if c not in cols:
            raise _err(path, "corpus.group_by" if c in columns else "corpus.select",
                       f"{c!r} is not a column of {manifest} (columns: {', '.join(cols)})")
    seen: dict[tuple[str, ...], int] = {}
    for line, r in enumerate(rows, start=2):
        if not all(r.get(k) in v for k, v in select.items()):
            continue
        values = tuple(r.get(c) or "" for c in columns)
        if any(v == "" for v in values):
            missing = columns[next(i for i, v in enumerate(values) if v == "")]
            raise _err(path, "corpus.group_by", f"{manifest}, line {line}: empty {missing!r} cell")
        seen.setdefault(values, line)
    if not seen:
        raise _err(path, "corpus", f"no row of {manifest} is left after select = {dict(select)}")
    out = []
    for values, line in seen.items():
        name = "-".join(values)
        if not GROUP_NAME.fullmatch(name):
            raise _err(path, "corpus.group_by", f"{manifest}, line {line}: group {name!r} "
                       "cannot name an output folder (use letters, digits, '.', '_', '-'; not starting with '.')")
        out.append((name, values))
    return out


def load_batch_spec(path: str | Path) -> BatchSpec:
    """Read and check a batch spec; SpecError naming the file and key on any problem.

    Every path of the result is absolute: units run on Dask workers whose working directory is not
    the client's (a scheduler and workers started elsewhere), so a path relative to the client's
    directory would name another file, or none, there."""
    path = Path(os.path.abspath(path))
    doc = parse_document(read_document(path), path)
    base = path.parent
    c = doc.corpus
    assert doc.fit is not None and c is not None  # BatchDocument requires both
    fit_path = Path(doc.fit) if Path(doc.fit).is_absolute() else base / doc.fit
    if not fit_path.is_file():
        raise _err(path, "fit", f"{fit_path}: {'is a directory, not a' if fit_path.is_dir() else 'no such'} fit spec")
    fit = load_spec(fit_path)  # its own errors name the fit spec file and key
    name = path.stem if doc.name is None else doc.name

    channels = fit.channels
    if doc.channels is not None:
        channels = doc.channels
        bad = [ch for ch in channels if ch not in fit.channels]
        if bad:
            raise _err(path, "channels", f"{bad} are not among the fit spec's channels {list(fit.channels)} "
                       f"({fit_path})")
    select = c.select

    # The fit spec's own reading of the data (label map, role map, file column) is kept; which rows
    # are read is the batch's.
    def corpus(**where: Any) -> CorpusSpec:
        return replace(fit.corpus_spec, **{"manifest": None, "files": (), "labels": (), "select": select, "limit": None,
                                      **where})

    hashes = {"batch spec": _sha(path, "top level", path), "fit spec": _sha(fit_path, "fit", path)}
    groups: list[Group] = []
    if c.manifest is not None:
        manifest = c.manifest if c.manifest.is_absolute() else base / c.manifest
        columns = c.group_by or ()
        for name_, values in _manifest_groups(manifest, columns, select, path):
            sel = dict(select)
            sel.update({col: (v,) for col, v in zip(columns, values)})
            spec = fit.with_options(corpus=corpus(manifest=manifest, select=sel), channels=channels,
                                    name=f"{name} / {name_}")
            where = ", ".join(f"{col} = {v}" for col, v in zip(columns, values))
            groups.append(Group(name_, spec, f"{where} in {manifest}"))
        hashes["manifest"] = _sha(manifest, "corpus.manifest", path)
        pooled_corpus = corpus(manifest=manifest)
    else:
        patterns = c.folders or ()
        mname = c.manifest_name or "manifest.csv"
        folders: list[Path] = []
        for pat in patterns:
            full = pat if Path(pat).is_absolute() else str(base / pat)
            hits = sorted(Path(p) for p in glob.glob(full) if Path(p).is_dir())
            if not hits:
                raise _err(path, "corpus.folders", f"{pat!r} matches no folder (relative to {base})")
            folders += [h for h in hits if h not in folders]
        for folder in folders:
            manifest = folder / mname
            if not manifest.is_file():
                raise _err(path, "corpus.folders", f"{folder} has no {mname}")
            if not GROUP_NAME.fullmatch(folder.name):
                raise _err(path, "corpus.folders", f"folder name {folder.name!r} cannot name an output folder "
                           "(use letters, digits, '.', '_', '-'; not starting with '.')")
            if any(g.name == folder.name for g in groups):
                raise _err(path, "corpus.folders", f"two folders are named {folder.name!r}: group names must differ")
            spec = fit.with_options(corpus=corpus(manifest=manifest), channels=channels,
                                    name=f"{name} / {folder.name}")
            groups.append(Group(folder.name, spec, str(folder)))
            hashes[f"manifest {folder.name}"] = _sha(manifest, "corpus.folders", path)
        # The pooled fit gets its data from the groups' loads, never from these: the manifests only
        # name its corpus (as data and label files both, which a corpus of files needs in pairs).
        manifests = tuple(g.spec.corpus_spec.manifest for g in groups if g.spec.corpus_spec.manifest is not None)
        pooled_corpus = corpus(files=manifests, labels=manifests)
    if len(groups) > MAX_GROUPS:
        raise _err(path, "corpus", f"{len(groups)} groups: at most {MAX_GROUPS}")

    pooled = doc.pooled.enabled
    # The pooled fit: shared dynamics, each group's targets as offset + scale of the first group's
    # ([model] speakers, by the "group" tag load_group puts on every utterance), unless the fit spec
    # already chose speakers or per-utterance offsets.
    own = fit.groups.speakers != "none" or fit.groups.offsets != "none"
    pooled_spec = fit.with_options(corpus=pooled_corpus, channels=channels, name=f"{name} (pooled)",
                                   **({} if own else {"speakers": "offset_scale", "speaker_column": "group"}))

    want = doc.posteriors.enabled
    mcmc: Any = None
    post_channels: tuple[str, ...] = ()
    if want:
        from coartic.mcmc.run import parse_config

        mcmc = parse_config(read_document(fit_path).get("mcmc"), fit_path, fit)  # errors name the fit spec's key
        post_channels = channels
        if mcmc.channels is not None:
            bad = [ch for ch in mcmc.channels if ch not in channels]
            if bad:
                raise _err(fit_path, "mcmc.channels", f"{bad} are not among the batch's channels {list(channels)} "
                           f"({path})")
            post_channels = tuple(c for c in channels if c in mcmc.channels)
    digest = hashlib.sha256(repr(sorted(hashes.items())).encode()).hexdigest()
    return BatchSpec(path=path, name=name, fit=fit, groups=tuple(groups), channels=channels, pooled=pooled,
                     pooled_spec=pooled_spec, fingerprint=digest, mcmc=mcmc, posterior_channels=post_channels)
