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

Every path is relative to the batch spec. Every error names the file and the key at fault, as the
fit spec's do (``coartic.fit.spec``).
"""

from __future__ import annotations

import csv
import glob
import hashlib
import io
import os
import re
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from coartic.errors import SpecError
from coartic.fit.spec import CorpusSpec, FitSpec, load_spec, read_document, synth_hint
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


def _strings(v: Any, path: Path, key: str) -> tuple[str, ...]:
    if isinstance(v, str):
        return (v,)
    if not isinstance(v, list) or not v or not all(isinstance(s, str) and s for s in v):
        raise _err(path, key, f"expected a non-empty list of strings, got {v!r}")
    return tuple(v)


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
    raw = read_document(path)
    base = path.parent
    allowed = {"name", "fit", "channels", "corpus", "pooled", "posteriors"}
    unknown = sorted(set(raw) - allowed)
    if unknown:
        raise _err(path, "top level", f"unknown key(s) {unknown}; allowed: {sorted(allowed)}")
    if not isinstance(raw.get("fit"), str) or not raw["fit"]:
        raise _err(path, "fit", "missing: the fit spec every unit uses, e.g. fit = 'synthetic.toml'")
    fit_path = Path(raw["fit"]) if Path(raw["fit"]).is_absolute() else base / raw["fit"]
    if not fit_path.is_file():
        raise _err(path, "fit", f"{fit_path}: {'is a directory, not a' if fit_path.is_dir() else 'no such'} fit spec")
    fit = load_spec(fit_path)  # its own errors name the fit spec file and key
    name = raw.get("name", path.stem)
    if not isinstance(name, str):
        raise _err(path, "name", f"expected a string, got {name!r}")

    channels = fit.channels
    if "channels" in raw:
        channels = _strings(raw["channels"], path, "channels")
        bad = [c for c in channels if c not in fit.channels]
        if bad:
            raise _err(path, "channels", f"{bad} are not among the fit spec's channels {list(fit.channels)} "
                       f"({fit_path})")

    c = raw.get("corpus")
    if not isinstance(c, dict):
        raise _err(path, "corpus", "missing: give manifest and group_by, or folders")
    c_allowed = {"manifest", "group_by", "folders", "manifest_name", "select"}
    unknown = sorted(set(c) - c_allowed)
    if unknown:
        raise _err(path, "corpus", f"unknown key(s) {unknown}; allowed: {sorted(c_allowed)}")
    select_raw = c.get("select", {})
    if not isinstance(select_raw, dict):
        raise _err(path, "corpus.select", f"expected a table column = [values], got {select_raw!r}")
    select = {k: tuple(str(x) for x in (v if isinstance(v, list) else [v])) for k, v in select_raw.items()}
    # The fit spec's own reading of the data (label map, role map, file column) is kept; which rows
    # are read is the batch's.
    def corpus(**where: Any) -> CorpusSpec:
        return replace(fit.corpus_spec, **{"manifest": None, "files": (), "labels": (), "select": select, "limit": None,
                                      **where})

    hashes = {"batch spec": _sha(path, "top level", path), "fit spec": _sha(fit_path, "fit", path)}
    groups: list[Group] = []
    if ("manifest" in c) == ("folders" in c):
        raise _err(path, "corpus", "give either manifest (with group_by) or folders, not both and not neither")
    if "manifest" in c:
        if not isinstance(c["manifest"], str) or not c["manifest"]:
            raise _err(path, "corpus.manifest", f"expected a path string, got {c['manifest']!r}")
        if "manifest_name" in c:
            raise _err(path, "corpus.manifest_name", "only with folders")
        manifest = Path(c["manifest"]) if Path(c["manifest"]).is_absolute() else base / c["manifest"]
        columns = _strings(c.get("group_by", []) or [], path, "corpus.group_by") if "group_by" in c else ()
        if not columns:
            raise _err(path, "corpus.group_by", "missing: the manifest column(s) naming the speaker or session")
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
        if "group_by" in c:
            raise _err(path, "corpus.group_by", "only with manifest (with folders, each folder is a group)")
        patterns = _strings(c["folders"], path, "corpus.folders")
        mname = c.get("manifest_name", "manifest.csv")
        if not isinstance(mname, str) or not mname or "/" in mname:
            raise _err(path, "corpus.manifest_name", f"expected a file name, got {mname!r}")
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

    p = raw.get("pooled", {})
    if not isinstance(p, dict) or sorted(set(p) - {"enabled"}):
        raise _err(path, "pooled", f"expected a table with enabled = true/false, got {p!r}")
    pooled = p.get("enabled", True)
    if not isinstance(pooled, bool):
        raise _err(path, "pooled.enabled", f"expected true or false, got {pooled!r}")
    # The pooled fit: shared dynamics, each group's targets as offset + scale of the first group's
    # ([model] speakers, by the "group" tag load_group puts on every utterance), unless the fit spec
    # already chose speakers or per-utterance offsets.
    own = fit.speakers != "none" or fit.offsets != "none"
    pooled_spec = fit.with_options(corpus=pooled_corpus, channels=channels, name=f"{name} (pooled)",
                                   **({} if own else {"speakers": "offset_scale", "speaker_column": "group"}))

    q = raw.get("posteriors", {})
    if not isinstance(q, dict) or sorted(set(q) - {"enabled"}):
        raise _err(path, "posteriors", f"expected a table with enabled = true/false, got {q!r}")
    want = q.get("enabled", False)
    if not isinstance(want, bool):
        raise _err(path, "posteriors.enabled", f"expected true or false, got {want!r}")
    mcmc: Any = None
    post_channels: tuple[str, ...] = ()
    if want:
        from coartic.mcmc.run import parse_config

        mcmc = parse_config(read_document(fit_path).get("mcmc"), fit_path, fit)  # errors name the fit spec's key
        post_channels = channels
        if mcmc.channels is not None:
            bad = [c for c in mcmc.channels if c not in channels]
            if bad:
                raise _err(fit_path, "mcmc.channels", f"{bad} are not among the batch's channels {list(channels)} "
                           f"({path})")
            post_channels = tuple(c for c in channels if c in mcmc.channels)
    digest = hashlib.sha256(repr(sorted(hashes.items())).encode()).hexdigest()
    return BatchSpec(path=path, name=name, fit=fit, groups=tuple(groups), channels=channels, pooled=pooled,
                     pooled_spec=pooled_spec, fingerprint=digest, mcmc=mcmc, posterior_channels=post_channels)
