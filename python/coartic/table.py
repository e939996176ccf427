"""The parameter table: per phoneme, per channel, the ten model parameters of MODEL.md §1.

The canonical file is JSON (schema ``coartic.table/1``, see docs/ARCHITECTURE.md); a tidy CSV
(``channel,phoneme,parameter,value[,q2.5,q16,q50,q84,q97.5]``, numbers only after the first three
columns) and ``to_dataframe()`` (pandas) are offered for spreadsheets and analysis; the CSV's
settings stay in the JSON beside it. The long CSV of earlier versions is still read.
Every float is written with ``repr`` so that ``load(save(table))`` gives back the same bits.
Loading validates everything and names the file, phoneme, channel and parameter at fault.
"""

from __future__ import annotations

import copy
import csv
import io
import json
import math
import re
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from coartic.errors import CoarticError
from coartic.extras import require
from coartic.outputs import atomic_write_text
from coartic.settings import CHANNEL_SETTINGS, DOMINANCES, RATE_SETTINGS
from coartic.textfile import TextDecodeError, read_text


SCHEMA = "coartic.table/1"
CHANNELS: tuple[str, ...] = ("ULO", "LLO", "ULP", "LLP", "LR", "JO")
# Tongue-tip and tongue-body height and advancement from EMA TT and TB sensors (docs/DATA.md):
# fitted like any channel (the model is per channel), driven as tongue FAPs by the face.
TONGUE_CHANNELS: tuple[str, ...] = ("TTH", "TTA", "TBH", "TBA")
ALL_CHANNELS: tuple[str, ...] = CHANNELS + ("LA",) + TONGUE_CHANNELS
PARAMETERS: tuple[str, ...] = (
    "target",
    "alpha",
    "theta_bw",
    "theta_fw",
    "c_bw",
    "c_fw",
    "k_r",
    "sigma",
    "psi",
    "delta",
)
N_PARAMS = len(PARAMETERS)
VARIANTS: tuple[str, ...] = ("original", "modified")
QUANTILES: tuple[str, ...] = ("q2.5", "q16", "q50", "q84", "q97.5")
TIDY_HEADER = ["channel", "phoneme", "parameter", "value"]  # table.csv's first columns (then QUANTILES)
PAUSE = "#"

INF = math.inf
# Target bounds depend on the channel and on the recording set-up (head-frame origin, EMA sensor
# placement), so by default they are unbounded; a table narrows them in its "bounds" section.
DEFAULT_BOUNDS: Mapping[str, tuple[float, float]] = {
    "target": (-INF, INF),
    "alpha": (0.0, INF),
    "theta_bw": (0.0, INF),
    "theta_fw": (0.0, INF),
    "c_bw": (0.5, 3.0),
    "c_fw": (0.5, 3.0),
    "k_r": (0.0, 1.0),
    "sigma": (-0.5, 0.5),
    "psi": (0.0, INF),
    "delta": (-0.08, 0.08),
}
# These must be strictly positive (they are fitted in log form); the other bounds are closed.
OPEN_LOWER: frozenset[str] = frozenset({"alpha", "theta_bw", "theta_fw", "psi"})
# The model's own domain of each parameter (MODEL.md §1): (low, high, low excluded). The Rust core
# refuses the same (params.rs validate_params; tests/python/test_table.py checks the two agree).
# DEFAULT_BOUNDS above is narrower (c, σ, δ): a table may widen its boxes, never past these.
MODEL_DOMAIN: Mapping[str, tuple[float, float, bool]] = {
    "target": (-INF, INF, False),
    "alpha": (0.0, INF, True),
    "theta_bw": (0.0, INF, True),
    "theta_fw": (0.0, INF, True),
    "c_bw": (0.0, INF, True),
    "c_fw": (0.0, INF, True),
    "k_r": (0.0, 1.0, False),
    "sigma": (-INF, INF, False),
    "psi": (0.0, INF, False),
    "delta": (-INF, INF, False),
}

CHANNEL_DEFAULTS: Mapping[str, Any] = {"unit": "mm", **{n: s.default for n, s in CHANNEL_SETTINGS.items()}}


class TableError(CoarticError, ValueError):
    """An invalid parameter table; the message names the file and the entry at fault."""


@dataclass
class ChannelSettings:
    """Per-channel globals: unit, β, edge extent Λ, apex fraction a, the reference phoneme, and the
    rate-aware options of docs/MODEL.md §2.1 (dominance, plateau fraction h, handover)."""

    reference_phoneme: str
    unit: str = "mm"
    beta: float = CHANNEL_SETTINGS["beta"].default
    edge_extent: float = CHANNEL_SETTINGS["edge_extent"].default
    apex_fraction: float = CHANNEL_SETTINGS["apex_fraction"].default
    dominance: str = CHANNEL_SETTINGS["dominance"].default
    plateau_fraction: float = CHANNEL_SETTINGS["plateau_fraction"].default
    handover: bool = CHANNEL_SETTINGS["handover"].default

    def rate_settings(self) -> dict[str, Any]:
        """The rate-aware options that differ from the defaults (what a table file records)."""
        return {n: getattr(self, n) for n in RATE_SETTINGS if getattr(self, n) != CHANNEL_DEFAULTS[n]}


@dataclass
class ParameterTable:
    """Model parameters per phoneme and channel, with optional bounds, uncertainty and reasons.

    Attributes
    ----------
    variant : {"original", "modified"}
    channels : dict channel -> ChannelSettings
    values : dict phoneme -> channel -> parameter -> float (natural units, all ten parameters)
    bounds : dict channel -> parameter -> (lo, hi), overriding ``DEFAULT_BOUNDS``
    uncertainty : dict phoneme -> channel -> parameter -> quantile name -> float
    reasons : dict phoneme -> channel -> parameter -> str (why this value)
    metadata : free-form dict (method, corpus, date, software, rmse per channel ...)
    source : where the table was read from (used in error messages), or "<table>"
    """

    variant: str = "modified"
    channels: dict[str, ChannelSettings] = field(default_factory=dict)
    values: dict[str, dict[str, dict[str, float]]] = field(default_factory=dict)
    bounds: dict[str, dict[str, tuple[float, float]]] = field(default_factory=dict)
    uncertainty: dict[str, dict[str, dict[str, dict[str, float]]]] = field(default_factory=dict)
    reasons: dict[str, dict[str, dict[str, str]]] = field(default_factory=dict)
    metadata: dict[str, Any] = field(default_factory=dict)
    source: str = field(default="<table>", compare=False)

    # ------------------------------------------------------------------ queries

    @property
    def phonemes(self) -> list[str]:
        """All phonemes of the table, in table order."""
        return list(self.values)

    def phonemes_for(self, channel: str) -> list[str]:
        """The phonemes that have parameters for ``channel``, in table order."""
        self._check_channel(channel)
        return [p for p, chans in self.values.items() if channel in chans]

    def bounds_for(self, channel: str, parameter: str) -> tuple[float, float]:
        """Effective (lo, hi) of a parameter in a channel: the table's override or the default."""
        if parameter not in DEFAULT_BOUNDS:
            raise TableError(f"{self.source}: unknown parameter {parameter!r} (known: {', '.join(PARAMETERS)})")
        return self.bounds.get(channel, {}).get(parameter, DEFAULT_BOUNDS[parameter])

    def to_matrix(
        self, channel: str, phonemes: Sequence[str] | None = None
    ) -> tuple[npt.NDArray[np.float64], float]:
        """Parameter matrix ``[len(phonemes), N_PARAMS]`` (columns in ``PARAMETERS`` order) and β.

        ``phonemes`` defaults to ``phonemes_for(channel)``; row i belongs to ``phonemes[i]``.
        """
        self._check_channel(channel)
        names = self.phonemes_for(channel) if phonemes is None else list(phonemes)
        out = np.empty((len(names), N_PARAMS), dtype=np.float64)
        for i, ph in enumerate(names):
            row = self.values.get(ph, {}).get(channel)
            if row is None:
                have = ", ".join(self.phonemes_for(channel))
                raise TableError(
                    f"{self.source}: phoneme {ph!r} has no parameters for channel {channel!r} "
                    f"(phonemes with {channel}: {have})"
                )
            out[i] = [row[name] for name in PARAMETERS]
        return out, float(self.channels[channel].beta)

    def set_from_matrix(
        self,
        channel: str,
        phonemes: Sequence[str],
        params: npt.ArrayLike,
        beta: float | None = None,
    ) -> None:
        """Write a parameter matrix (as from ``to_matrix``) back into the table, then validate.

        New phonemes are added. On a validation error the table is left unchanged.
        """
        self._check_channel(channel)
        mat = np.asarray(params, dtype=np.float64)
        if mat.shape != (len(phonemes), N_PARAMS):
            raise TableError(
                f"{self.source}: params has shape {mat.shape}, expected ({len(phonemes)}, {N_PARAMS}) "
                f"for {len(phonemes)} phonemes of channel {channel!r}"
            )
        if len(set(phonemes)) != len(phonemes):
            dup = next(p for p in phonemes if list(phonemes).count(p) > 1)
            raise TableError(f"{self.source}: phoneme {dup!r} appears twice in the phoneme list")
        saved_values = copy.deepcopy(self.values)
        saved_beta = self.channels[channel].beta
        for ph, row in zip(phonemes, mat):
            self.values.setdefault(ph, {})[channel] = {n: float(v) for n, v in zip(PARAMETERS, row)}
        if beta is not None:
            self.channels[channel].beta = float(beta)
        try:
            self.validate()
        except TableError:
            self.values = saved_values
            self.channels[channel].beta = saved_beta
            raise

    def _check_channel(self, channel: str) -> None:
        if channel not in self.channels:
            raise TableError(
                f"{self.source}: channel {channel!r} is not in the table (channels: {', '.join(self.channels) or 'none'})"
            )

    # --------------------------------------------------------------- validation

    def validate(self) -> None:
        """Check everything; raise ``TableError`` naming the first entry at fault."""
        src = self.source
        if self.variant not in VARIANTS:
            raise TableError(f"{src}: variant {self.variant!r} is not one of {', '.join(VARIANTS)}")
        if not self.channels:
            raise TableError(f"{src}: the table has no channels")
        for ch, cs in self.channels.items():
            where = f"{src}: channel {ch!r}"
            if ch not in ALL_CHANNELS:
                raise TableError(f"{src}: unknown channel {ch!r} (known: {', '.join(ALL_CHANNELS)})")
            if not isinstance(cs.unit, str) or not cs.unit:
                raise TableError(f"{where}: unit must be a non-empty string, got {cs.unit!r}")
            for name, setting in CHANNEL_SETTINGS.items():
                problem = setting.problem(getattr(cs, name))
                if problem is not None:
                    raise TableError(f"{where}: {name} = {getattr(cs, name)!r} {problem}")
            if not isinstance(cs.reference_phoneme, str) or cs.reference_phoneme not in self.values or ch not in self.values[cs.reference_phoneme]:
                raise TableError(
                    f"{where}: reference phoneme {cs.reference_phoneme!r} has no parameters for {ch}"
                )
        for ch, per in self.bounds.items():
            if ch not in self.channels:
                raise TableError(f"{src}: bounds given for channel {ch!r}, which the table does not have")
            for name, (lo, hi) in per.items():
                if name not in DEFAULT_BOUNDS:
                    raise TableError(f"{src}: bounds for channel {ch!r}: unknown parameter {name!r} (known: {', '.join(PARAMETERS)})")
                if not (_is_number(lo) and _is_number(hi)) or math.isnan(lo) or math.isnan(hi) or not lo < hi:
                    raise TableError(f"{src}: bounds for channel {ch!r}, {name}: [{lo}, {hi}] is not an interval lo < hi")
        for ph, chans in self.values.items():
            if not isinstance(ph, str) or not ph:
                raise TableError(f"{src}: phoneme names must be non-empty strings, got {ph!r}")
            for ch, row in chans.items():
                where = f"{src}: phoneme {ph!r}, channel {ch!r}"
                if ch not in self.channels:
                    raise TableError(
                        f"{where}: the channel is not declared in 'channels' (declared: {', '.join(self.channels)})"
                    )
                unknown = [n for n in row if n not in DEFAULT_BOUNDS]
                if unknown:
                    raise TableError(f"{where}: unknown parameter {unknown[0]!r} (known: {', '.join(PARAMETERS)})")
                missing = [n for n in PARAMETERS if n not in row]
                if missing:
                    raise TableError(f"{where}: missing parameter(s) {', '.join(missing)}")
                for name in PARAMETERS:
                    lo, hi = self.bounds_for(ch, name)
                    _check_number(where, name, row[name], lo, hi, open_lower=name in OPEN_LOWER and lo == 0.0)
                    problem = domain_problem(name, row[name])
                    if problem is not None:  # the table's own bounds let it through: they are too wide
                        raise TableError(f"{where}: {name} = {row[name]!r} {problem}, the model's domain of "
                                         f"{name} (MODEL.md §1), whatever the table's bounds say")
            for ch in chans:
                if self.channels[ch].reference_phoneme == ph and chans[ch]["alpha"] != 1.0:
                    raise TableError(
                        f"{src}: phoneme {ph!r}, channel {ch!r}: alpha = {chans[ch]['alpha']!r}, but {ph!r} is the "
                        f"reference phoneme of {ch}, whose alpha is fixed to 1"
                    )
        for ph, u_chans in self.uncertainty.items():
            for ch, u_per in u_chans.items():
                for name, qs in u_per.items():
                    where = f"{src}: uncertainty of phoneme {ph!r}, channel {ch!r}, {name}"
                    if ph not in self.values or ch not in self.values[ph] or name not in PARAMETERS:
                        raise TableError(f"{where}: no such parameter in the table")
                    for q, v in qs.items():
                        if q not in QUANTILES:
                            raise TableError(f"{where}: unknown quantile {q!r} (known: {', '.join(QUANTILES)})")
                        if not _is_number(v) or not math.isfinite(v):
                            raise TableError(f"{where}: {q} = {v!r} is not a finite number")
                    present = [qs[q] for q in QUANTILES if q in qs]
                    if any(b < a for a, b in zip(present, present[1:])):
                        raise TableError(f"{where}: quantiles are not in increasing order: {qs}")
        for ph, r_chans in self.reasons.items():
            for ch, r_per in r_chans.items():
                for name, text in r_per.items():
                    if name not in PARAMETERS or not isinstance(text, str):
                        raise TableError(
                            f"{src}: reason for phoneme {ph!r}, channel {ch!r}, {name!r} must name a parameter "
                            f"and be a string"
                        )
        if not isinstance(self.metadata, dict):
            raise TableError(f"{src}: metadata must be an object")

    # ---------------------------------------------------------------------- JSON

    def to_json_dict(self) -> dict[str, Any]:
        """The JSON object of the ``coartic.table/1`` schema (optional sections only when non-empty)."""
        doc: dict[str, Any] = {
            "schema": SCHEMA,
            "variant": self.variant,
            "channels": {
                ch: {
                    "unit": cs.unit,
                    "beta": cs.beta,
                    "edge_extent": cs.edge_extent,
                    "apex_fraction": cs.apex_fraction,
                    "reference_phoneme": cs.reference_phoneme,
                    **cs.rate_settings(),
                }
                for ch, cs in self.channels.items()
            },
            "phonemes": {
                ph: {ch: {n: row[n] for n in PARAMETERS} for ch, row in chans.items()}
                for ph, chans in self.values.items()
            },
        }
        if self.bounds:
            # JSON has no infinity: an open end is written as null.
            doc["bounds"] = {
                ch: {n: [_inf_to_none(lo), _inf_to_none(hi)] for n, (lo, hi) in per.items()}
                for ch, per in self.bounds.items()
            }
        if self.uncertainty:
            doc["uncertainty"] = self.uncertainty
        if self.reasons:
            doc["reasons"] = self.reasons
        if self.metadata:
            doc["metadata"] = self.metadata
        return doc

    def save(self, path: str | Path) -> None:
        """Validate, then write JSON (``.json``) or long CSV (``.csv``), chosen by the suffix."""
        self.validate()
        path = Path(path)
        # whole or not at all: written aside, flushed and renamed (coartic.outputs)
        if path.suffix.lower() == ".csv":
            atomic_write_text(path, self.to_csv())
        else:
            # json writes floats with repr: the shortest string that reads back to the same bits.
            try:
                text = json.dumps(self.to_json_dict(), indent=2, ensure_ascii=False, allow_nan=False)
            except (TypeError, ValueError) as exc:
                # Only metadata is free-form enough to hold NaN or objects JSON cannot write.
                raise TableError(f"{path}: metadata cannot be written as JSON: {exc}") from None
            atomic_write_text(path, text + "\n")

    @classmethod
    def from_json_dict(cls, doc: Any, source: str = "<table>") -> ParameterTable:
        """Build and validate a table from a parsed JSON object."""
        if not isinstance(doc, dict):
            raise TableError(f"{source}: expected a JSON object at the top level")
        schema = doc.get("schema")
        if schema != SCHEMA:
            raise TableError(f"{source}: schema is {schema!r}, this version of coartic reads {SCHEMA!r}")
        known = {"schema", "variant", "channels", "phonemes", "bounds", "uncertainty", "reasons", "metadata"}
        extra = sorted(set(doc) - known)
        if extra:
            raise TableError(f"{source}: unknown top-level key {extra[0]!r} (known: {', '.join(sorted(known))})")
        for key in ("variant", "channels", "phonemes"):
            if key not in doc:
                raise TableError(f"{source}: missing required key {key!r}")
        channels: dict[str, ChannelSettings] = {}
        for ch, cdoc in _obj(doc["channels"], f"{source}: channels").items():
            where = f"{source}: channel {ch!r}"
            cdoc = _obj(cdoc, where)
            extra = sorted(set(cdoc) - {"unit", "reference_phoneme", *CHANNEL_SETTINGS})
            if extra:
                raise TableError(f"{where}: unknown key {extra[0]!r}")
            if "reference_phoneme" not in cdoc:
                raise TableError(f"{where}: missing 'reference_phoneme'")
            channels[ch] = ChannelSettings(
                reference_phoneme=cdoc["reference_phoneme"],
                unit=cdoc.get("unit", CHANNEL_DEFAULTS["unit"]),
                beta=_num(where, "beta", cdoc.get("beta", CHANNEL_DEFAULTS["beta"])),
                edge_extent=_num(where, "edge_extent", cdoc.get("edge_extent", CHANNEL_DEFAULTS["edge_extent"])),
                apex_fraction=_num(where, "apex_fraction", cdoc.get("apex_fraction", CHANNEL_DEFAULTS["apex_fraction"])),
                dominance=cdoc.get("dominance", CHANNEL_DEFAULTS["dominance"]),
                plateau_fraction=_num(where, "plateau_fraction",
                                      cdoc.get("plateau_fraction", CHANNEL_DEFAULTS["plateau_fraction"])),
                handover=cdoc.get("handover", CHANNEL_DEFAULTS["handover"]),
            )
        values: dict[str, dict[str, dict[str, float]]] = {}
        for ph, pdoc in _obj(doc["phonemes"], f"{source}: phonemes").items():
            values[ph] = {}
            for ch, row in _obj(pdoc, f"{source}: phoneme {ph!r}").items():
                where = f"{source}: phoneme {ph!r}, channel {ch!r}"
                values[ph][ch] = {n: _num(where, n, v) for n, v in _obj(row, where).items()}
        bounds: dict[str, dict[str, tuple[float, float]]] = {}
        for ch, per in _obj(doc.get("bounds", {}), f"{source}: bounds").items():
            bounds[ch] = {}
            for n, pair in _obj(per, f"{source}: bounds of {ch!r}").items():
                if not isinstance(pair, list) or len(pair) != 2:
                    raise TableError(f"{source}: bounds for channel {ch!r}, {n}: expected [lo, hi], got {pair!r}")
                lo = -INF if pair[0] is None else _num(f"{source}: bounds for channel {ch!r}", n, pair[0])
                hi = INF if pair[1] is None else _num(f"{source}: bounds for channel {ch!r}", n, pair[1])
                bounds[ch][n] = (lo, hi)
        uncertainty: dict[str, dict[str, dict[str, dict[str, float]]]] = {}
        for ph, pdoc in _obj(doc.get("uncertainty", {}), f"{source}: uncertainty").items():
            for ch, per in _obj(pdoc, f"{source}: uncertainty of {ph!r}").items():
                for n, qs in _obj(per, f"{source}: uncertainty of {ph!r}, {ch!r}").items():
                    where = f"{source}: uncertainty of phoneme {ph!r}, channel {ch!r}, {n}"
                    uncertainty.setdefault(ph, {}).setdefault(ch, {})[n] = {
                        q: _num(where, q, v) for q, v in _obj(qs, where).items()
                    }
        reasons = _obj(doc.get("reasons", {}), f"{source}: reasons")
        metadata = _obj(doc.get("metadata", {}), f"{source}: metadata")
        table = cls(
            variant=doc["variant"],
            channels=channels,
            values=values,
            bounds=bounds,
            uncertainty=uncertainty,
            reasons={ph: {ch: dict(per) for ch, per in _obj(c, f"{source}: reasons of {ph!r}").items()} for ph, c in reasons.items()},
            metadata=dict(metadata),
            source=source,
        )
        table.validate()
        return table

    @classmethod
    def load(cls, path: str | Path) -> ParameterTable:
        """Read and validate a table from JSON or (by suffix ``.csv``) CSV: a tidy CSV's settings
        come from the JSON of the same name beside it (``from_csv``)."""
        path = Path(path)
        try:
            text = read_text(path, "table")
        except OSError as exc:
            raise TableError(f"{path}: cannot read the table: {exc.strerror}") from None
        except TextDecodeError as exc:
            raise TableError(str(exc)) from None
        if path.suffix.lower() == ".csv":
            beside = path.with_suffix(".json")
            tidy = text.startswith(",".join(TIDY_HEADER))
            return cls.from_csv(text, source=str(path), settings=cls.load(beside) if tidy and beside.is_file() else None)
        return cls.from_json_dict(parse_json(text, str(path)), source=str(path))

    # ----------------------------------------------------------------------- CSV and pandas

    def tidy_rows(self) -> list[tuple[str, str, str, float, list[float | None]]]:
        """(channel, phoneme, parameter, value, quantiles or None each) for every value: the rows of
        ``table.csv`` and of ``to_dataframe``, channel by channel, phonemes as in the table."""
        rows = []
        for ch in self.channels:
            for ph, chans in self.values.items():
                if ch not in chans:
                    continue
                for name in PARAMETERS:
                    qs = self.uncertainty.get(ph, {}).get(ch, {}).get(name, {})
                    rows.append((ch, ph, name, float(chans[ch][name]), [qs.get(q) for q in QUANTILES]))
        return rows

    def to_csv(self) -> str:
        """Tidy CSV: ``channel,phoneme,parameter,value`` and, when the table has any uncertainty,
        the quantile columns (empty where none), one row per channel, phoneme and parameter. Every
        cell after the first three is a number (``repr``: read back bit for bit), so pandas reads
        them as float64. The channel settings (reference phoneme, β, unit, ...), the variant,
        bounds and metadata are not in it: they are in ``table.json`` beside it, which ``load``
        reads with it (``from_csv``)."""
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        with_q = bool(self.uncertainty)
        w.writerow(TIDY_HEADER + (list(QUANTILES) if with_q else []))
        for ch, ph, name, value, qs in self.tidy_rows():
            extra = ["" if q is None else repr(float(q)) for q in qs] if with_q else []
            w.writerow([ch, ph, name, repr(value)] + extra)
        return buf.getvalue()

    def to_dataframe(self) -> Any:
        """The values (and quantiles, NaN where none) as a pandas DataFrame, the rows and columns
        of ``table.csv``; the quantile columns are always there.

        >>> from coartic.demo import illustrative_table   # /# a p f t/ on LLO
        >>> df = illustrative_table().to_dataframe()
        >>> df.shape                                         # 5 phonemes x 10 parameters; 4 + 5 columns
        (50, 9)
        >>> df.query("phoneme == 'p' and parameter == 'k_r'")[["channel", "value"]].values.tolist()
        [['LLO', 1.0]]
        >>> str(df["value"].dtype), str(df["q50"].dtype)
        ('float64', 'float64')
        """
        require("dataframe", "to_dataframe()")
        import pandas as pd

        rows = [(ch, ph, name, value, *[math.nan if q is None else float(q) for q in qs])
                for ch, ph, name, value, qs in self.tidy_rows()]
        return pd.DataFrame(rows, columns=[*TIDY_HEADER, *QUANTILES])

    @classmethod
    def from_csv(cls, text: str, source: str = "<csv>", settings: ParameterTable | None = None) -> ParameterTable:
        """Read a table's CSV and validate it.

        The tidy CSV (``to_csv``) carries the values and quantiles only; ``settings`` (the table
        of ``table.json`` beside it) gives the variant, channel settings, bounds and metadata, and
        must have the CSV's channels. The long CSV of earlier versions (``phoneme,channel,...``
        with ``*`` rows for the settings) is read on its own.
        """
        reader = csv.reader(io.StringIO(text))
        try:
            header = next(reader)
        except StopIteration:
            raise TableError(f"{source}: empty CSV file") from None
        if header[:4] == TIDY_HEADER:
            return cls._from_tidy_csv(header, reader, source, settings)
        base = ["phoneme", "channel", "parameter", "value"]
        if header not in (base, base + list(QUANTILES)):
            raise TableError(
                f"{source}: line 1: header must be {','.join(TIDY_HEADER)}[,{','.join(QUANTILES)}], got {','.join(header)}"
            )
        variant = "modified"
        settings_: dict[str, dict[str, str]] = {}
        values: dict[str, dict[str, dict[str, float]]] = {}
        uncertainty: dict[str, dict[str, dict[str, dict[str, float]]]] = {}
        for where, ph, ch, name, value, cells in _csv_records(reader, header, source, phoneme_first=True):
            if ph == "*":
                if ch == "*":
                    if name != "variant":
                        raise TableError(f"{where}: unknown table setting {name!r}")
                    variant = value
                else:
                    if name not in ("unit", "reference_phoneme", *CHANNEL_SETTINGS):
                        raise TableError(f"{where}: unknown channel setting {name!r}")
                    settings_.setdefault(ch, {})[name] = value
                continue
            _put_value(values, uncertainty, where, ph, ch, name, value, cells)
        channels: dict[str, ChannelSettings] = {}
        for ch, s in settings_.items():
            where = f"{source}: channel {ch!r}"
            if "reference_phoneme" not in s:
                raise TableError(f"{where}: missing the row '*,{ch},reference_phoneme,<phoneme>'")
            # a setting's cell parsed as its kind (coartic.settings), absent ones at their defaults
            given: dict[str, Any] = {
                name: (_parse_bool(where, name, s[name]) if setting.flag else s[name] if setting.choices
                       else _parse_float(where, name, s[name]))
                for name, setting in CHANNEL_SETTINGS.items() if name in s}
            channels[ch] = ChannelSettings(reference_phoneme=s["reference_phoneme"],
                                           unit=s.get("unit", CHANNEL_DEFAULTS["unit"]), **given)
        table = cls(variant=variant, channels=channels, values=values, uncertainty=uncertainty, source=source)
        table.validate()
        return table

    @classmethod
    def _from_tidy_csv(cls, header: list[str], reader: Any, source: str,
                       settings: ParameterTable | None) -> ParameterTable:
        if header not in (TIDY_HEADER, TIDY_HEADER + list(QUANTILES)):
            raise TableError(f"{source}: line 1: header must be {','.join(TIDY_HEADER)}[,{','.join(QUANTILES)}], "
                             f"got {','.join(header)}")
        if settings is None:
            raise TableError(f"{source}: a table CSV holds the values only; its variant and channel settings are "
                             "in the table JSON written beside it (same name, .json), which is missing: load that")
        values: dict[str, dict[str, dict[str, float]]] = {}
        uncertainty: dict[str, dict[str, dict[str, dict[str, float]]]] = {}
        for where, ph, ch, name, value, cells in _csv_records(reader, header, source, phoneme_first=False):
            if name not in PARAMETERS:
                raise TableError(f"{where}: unknown parameter {name!r} (parameters: {', '.join(PARAMETERS)})")
            if ch not in settings.channels:
                raise TableError(f"{where}: channel {ch!r} is not in {settings.source} "
                                 f"(channels: {', '.join(settings.channels)})")
            _put_value(values, uncertainty, where, ph, ch, name, value, cells)
        table = copy.deepcopy(settings)
        table.values, table.uncertainty, table.source = values, uncertainty, source
        table.validate()
        return table

    # ---------------------------------------------------------------- building

    @classmethod
    def from_rows(
        cls,
        rows: Mapping[str, Mapping[str, Mapping[str, float]]],
        reference: Mapping[str, str],
        variant: str = "modified",
        settings: Mapping[str, Mapping[str, Any]] | None = None,
        reasons: Mapping[str, Mapping[str, Mapping[str, str]]] | None = None,
    ) -> ParameterTable:
        """Build a validated table from ``rows[phoneme][channel][parameter]``.

        ``reference[channel]`` names the reference phoneme; ``settings[channel]`` may set
        unit, beta, edge_extent, apex_fraction, dominance, plateau_fraction, handover.
        """
        allowed = {"unit", *CHANNEL_SETTINGS}
        for ch, given in (settings or {}).items():
            extra = sorted(set(given) - allowed)
            if extra:
                raise TableError(f"settings of channel {ch!r}: unknown key {extra[0]!r} (known: {', '.join(sorted(allowed))})")
        channels = {
            ch: ChannelSettings(reference_phoneme=ref, **dict((settings or {}).get(ch, {})))
            for ch, ref in reference.items()
        }
        table = cls(
            variant=variant,
            channels=channels,
            values={ph: {ch: {n: float(v) for n, v in row.items()} for ch, row in c.items()} for ph, c in rows.items()},
            reasons={ph: {ch: dict(r) for ch, r in c.items()} for ph, c in (reasons or {}).items()},
        )
        table.validate()
        return table


# ---------------------------------------------------------------------- helpers


# Deeper than this a table is not a table (its own sections nest 4 levels; metadata a few more), and
# Python's JSON reader and writer recurse: a 100000-deep document raised RecursionError. docs/LIMITS.md.
MAX_JSON_DEPTH = 64


def parse_json(text: str, source: str) -> Any:
    """A JSON document with every object's keys unique (json keeps the last of two silently), at
    most MAX_JSON_DEPTH deep, its integers within Python's 4300 digits; else a TableError."""

    def unique(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for k, v in pairs:
            if k in out:
                raise TableError(f"{source}: {_line_of_second_key(text, k)}key {k!r} appears twice in one "
                                 "object (JSON would keep the last silently)")
            out[k] = v
        return out

    depth = deepest = 0
    in_string = escaped = False
    for ch in text:  # brackets outside strings: cheap, and before the recursive reader sees them
        if in_string:
            if escaped:
                escaped = False
            elif ch == "\\":
                escaped = True
            elif ch == '"':
                in_string = False
        elif ch == '"':
            in_string = True
        elif ch in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif ch in "]}":
            depth -= 1
    if deepest > MAX_JSON_DEPTH:
        raise TableError(f"{source}: JSON nested {deepest} levels deep (a table has at most {MAX_JSON_DEPTH})")
    try:
        return json.loads(text, object_pairs_hook=unique)
    except json.JSONDecodeError as exc:
        raise TableError(f"{source}: line {exc.lineno}, column {exc.colno}: invalid JSON: {exc.msg}") from None
    except RecursionError:
        raise TableError(f"{source}: JSON nested too deeply") from None
    except ValueError as exc:  # e.g. "Exceeds the limit (4300 digits) for integer string conversion"
        if isinstance(exc, TableError):
            raise
        raise TableError(f"{source}: a number cannot be read: {exc}") from None


def _line_of_second_key(text: str, key: str) -> str:
    hits = [m.start() for m in re.finditer(re.escape(json.dumps(key)) + r"\s*:", text)]
    # only when the key occurs just twice is the second occurrence surely the duplicate
    return f"line {text.count(chr(10), 0, hits[1]) + 1}: " if len(hits) == 2 else ""


def _obj(x: Any, where: str) -> dict[str, Any]:
    if not isinstance(x, dict):
        raise TableError(f"{where}: expected a JSON object, got {type(x).__name__}")
    return x


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _num(where: str, name: str, v: Any) -> float:
    # bool is an int subclass; true/false in a table is always a mistake.
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise TableError(f"{where}: {name} = {v!r:.60} is not a number")
    try:
        return float(v)
    except OverflowError:  # an integer of hundreds of digits
        raise TableError(f"{where}: {name} = {str(v)[:20]}... ({len(str(v))} digits) is not a finite number") from None


def _parse_bool(where: str, name: str, text: str) -> bool:
    if text not in ("true", "false"):
        raise TableError(f"{where}: {name} = {text!r} is not true or false")
    return text == "true"


def _parse_float(where: str, name: str, text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise TableError(f"{where}: {name} = {text!r} is not a number") from None


def number_problem(v: Any, lo: float, hi: float, open_lower: bool) -> str | None:
    """Why ``v`` is not a number in [lo, hi] (``(lo, hi]`` with ``open_lower``), or None: the one
    wording of a value outside its interval, for tables and specs alike."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return "is not a number"
    if not math.isfinite(v):
        return "is not finite"
    below = v <= lo if open_lower else v < lo
    if below or v > hi:
        interval = ("(" if open_lower or lo == -INF else "[") + f"{lo:g}, {hi:g}" + (")" if hi == INF else "]")
        return f"is outside {interval}"
    return None


def domain_problem(name: str, v: Any) -> str | None:
    """Why ``v`` is not a value of parameter ``name`` in the model's domain (MODEL_DOMAIN), or None."""
    lo, hi, open_lower = MODEL_DOMAIN[name]
    return number_problem(v, lo, hi, open_lower)


def _csv_records(reader: Any, header: list[str], source: str,
                 phoneme_first: bool) -> Iterator[tuple[str, str, str, str, str, list[str]]]:
    """A table CSV's rows after the header, each once: (where, phoneme, channel, parameter, value,
    quantile cells), for the tidy form (channel first) and the long form of earlier versions."""
    seen: dict[tuple[str, str, str], int] = {}
    for lineno, rec in enumerate(reader, start=2):
        if not rec:
            continue
        if len(rec) != len(header):
            raise TableError(f"{source}: line {lineno}: expected {len(header)} fields, got {len(rec)}")
        ph, ch, name, value = rec[:4] if phoneme_first else (rec[1], rec[0], rec[2], rec[3])
        where = f"{source}: line {lineno}: phoneme {ph!r}, channel {ch!r}"
        if (ph, ch, name) in seen:
            # the later row would silently win: which value is meant cannot be known
            raise TableError(f"{where}: {name} is given twice (first on line {seen[ph, ch, name]})")
        seen[ph, ch, name] = lineno
        yield where, ph, ch, name, value, rec[4:]


def _put_value(values: dict[str, dict[str, dict[str, float]]],
               uncertainty: dict[str, dict[str, dict[str, dict[str, float]]]],
               where: str, ph: str, ch: str, name: str, value: str, cells: list[str]) -> None:
    """One CSV row's value and its quantiles (empty cells: none) into the table's dicts."""
    values.setdefault(ph, {}).setdefault(ch, {})[name] = _parse_float(where, name, value)
    for q, cell in zip(QUANTILES, cells):
        if cell != "":
            uncertainty.setdefault(ph, {}).setdefault(ch, {}).setdefault(name, {})[q] = _parse_float(
                where, f"{name} {q}", cell)


def _check_number(where: str, name: str, v: Any, lo: float, hi: float, open_lower: bool) -> None:
    problem = number_problem(v, lo, hi, open_lower)
    if problem is not None:
        raise TableError(f"{where}: {name} = {v!r} {problem}")


def _inf_to_none(x: float) -> float | None:
    return None if math.isinf(x) else x


def parameter_index(name: str) -> int:
    """Column of a parameter in the parameter matrix (``PARAMETERS.index``), with a clear error."""
    try:
        return PARAMETERS.index(name)
    except ValueError:
        raise TableError(f"unknown parameter {name!r} (known: {', '.join(PARAMETERS)})") from None

