"""The fit specification: a TOML file (``fit/*.toml``) describing one least-squares fit.

Every path in a spec is relative to the spec file. Every error names the spec file and the key at
fault, e.g. ``fit/synthetic.toml: [engine] name = 'foo': unknown engine (scipy, nlopt, casadi)``.

See ``fit/template.toml`` for a commented example of every key.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from coartic.errors import CoarticError
from coartic.textfile import TextDecodeError, read_text
from coartic.io.errors import DataError
from coartic.io.roles import RoleMap
from coartic.settings import CHANNEL_SETTINGS, default
from coartic.table import ALL_CHANNELS, CHANNELS, PARAMETERS, VARIANTS, ChannelSettings, domain_problem

ENGINES: tuple[str, ...] = ("scipy", "nlopt", "casadi")
# [validate] group: what a k-fold validation holds out together (manifest columns, or the file).
VALIDATE_GROUPS: tuple[str, ...] = ("utterance", "sentence", "rate", "speaker", "repetition")

# Starting values of the dynamics; targets start from the data (mean value at the target times).
DEFAULT_START: dict[str, float] = {
    "target": 0.0, "alpha": 1.0, "theta_bw": 30.0, "theta_fw": 30.0, "c_bw": 1.0, "c_fw": 1.0,
    "k_r": 0.5, "sigma": 0.0, "psi": 500.0, "delta": 0.0,
}
# Fitting bounds (natural units). MODEL.md allows (0, inf) for alpha, theta and psi; a fit needs
# finite boxes (global engines search them, and a log transform needs them away from 0), so these
# are wide practical boxes. Target bounds default to the data range widened by `target_margin`.
DEFAULT_FIT_BOUNDS: dict[str, tuple[float, float]] = {
    "alpha": (1e-2, 1e2), "theta_bw": (0.5, 2000.0), "theta_fw": (0.5, 2000.0),
    "c_bw": (0.5, 3.0), "c_fw": (0.5, 3.0), "k_r": (0.0, 1.0), "sigma": (-0.5, 0.5),
    "psi": (10.0, 1e5), "delta": (-0.08, 0.08),
}
DEFAULT_BETA_BOUNDS: tuple[float, float] = (0.05, 20.0)
# The model of a spec that sets nothing: the one that beat the step model (each phoneme's mean) held
# out on the real recordings we have (bench/real_data.py, docs/REAL_DATA.md): the rate-aware
# dominance (plateau + handover), every phoneme's target free but one theta_bw and one theta_fw per
# channel shared by every phoneme ([parameters] shared; only when [parameters] free is not given
# either), and every target drawn toward the data's own mean over that phoneme's segments with sd
# DEFAULT_TARGET_PRIOR mm ([parameters] target_prior). Per-phoneme dynamics fitted the training data
# better and predicted held-out speech worse there.
DEFAULT_FREE: tuple[str, ...] = ("target", "theta_bw", "theta_fw")
DEFAULT_SHARED: tuple[str, ...] = ("theta_bw", "theta_fw")
DEFAULT_TARGET_PRIOR: float | None = 0.3
SPEC_MODEL_DEFAULTS: dict[str, Any] = {"dominance": "plateau", "handover": True}
DEFAULT_STAGES: tuple[tuple[str, ...], ...] = (
    ("target",),
    ("alpha", "theta_bw", "theta_fw", "c_bw", "c_fw", "delta"),
    ("k_r", "sigma", "psi", "beta"),
)
# [fit] defaults: multi-start estimation (coartic.fit.multistart; measured in bench/multistart.py)
DEFAULT_STARTS = 32
DEFAULT_PROBE = 10  # evaluations per stage in the probe every start gets


class SpecError(CoarticError, ValueError):
    """A fit specification that cannot be used; the message names the file and the key, and so do
    the attributes ``file`` (the spec's path), ``key`` (``"model.beta"``, ``"override #2.fixed.k_r"``)
    and, where one is at fault, ``phoneme`` (its name), for programs that must not parse prose."""

    file: Path | None = None
    key: str | None = None

    @classmethod
    def at(cls, file: Path, key: str, message: str, phoneme: str | None = None) -> SpecError:
        """``file: [key] message``, with the place in the attributes as well."""
        err = cls(f"{file}: [{key}] {message}")
        err.file, err.key, err.phoneme = file, key, phoneme
        return err


@dataclass(frozen=True)
class Override:
    """Per-phoneme (optionally per-channel) changes to which parameters are free, their start and bounds."""

    phonemes: tuple[str, ...]
    channels: tuple[str, ...] | None = None  # None: every channel
    fixed: dict[str, float] = field(default_factory=dict)  # fixed at this value
    free: tuple[str, ...] = ()  # made free (even if not in the global list)
    start: dict[str, float] = field(default_factory=dict)
    bounds: dict[str, tuple[float, float]] = field(default_factory=dict)

    def applies(self, phoneme: str, channel: str) -> bool:
        return phoneme in self.phonemes and (self.channels is None or channel in self.channels)


@dataclass(frozen=True)
class Tie:
    """Parameters shared by a group of phonemes (e.g. θ and c by place of articulation): the first
    phoneme of the group present in a channel's data carries the value, the others take it."""

    phonemes: tuple[str, ...]
    parameters: tuple[str, ...]
    channels: tuple[str, ...] | None = None  # None: every channel


@dataclass(frozen=True)
class Shrink:
    """Shrinkage of a class of phonemes toward its class mean (``[[shrink]]``): for each parameter,
    one penalty row per member, ``prior_noise · (v_i − mean_class(v)) / sd`` (v the value, or its
    logarithm with ``log``), the mean over every member present in the channel's data (fixed ones
    count in the mean)."""

    phonemes: tuple[str, ...]
    parameters: tuple[str, ...]
    sd: float
    log: bool = False
    channels: tuple[str, ...] | None = None  # None: every channel
    key: str = "shrink"  # the spec key its errors and reports are named by ("shrink #2")


# Settings ``[choose]`` / ``coartic fit --choose`` may choose by cross-validation, and which end of a
# grid is the stronger regularisation (the one-standard-error rule moves toward it): -1 smaller values,
# +1 larger values, 0 no such direction.
CHOOSABLE: dict[str, int] = {"shrink.sd": -1, "prior_noise": +1, "plateau_fraction": 0, "target_prior": -1}
CHOOSE_RULES: tuple[str, ...] = ("min", "1se")


@dataclass(frozen=True)
class Choose:
    """``[choose]``: a setting chosen by k-fold cross-validation on the training data."""

    key: str  # "shrink.sd" (every [[shrink]]), "shrink #2.sd" (one), "prior_noise", "plateau_fraction", "target_prior"
    values: tuple[float, ...]
    group: str = "utterance"  # VALIDATE_GROUPS: what a fold holds out together
    folds: int = 5
    rule: str = "1se"  # "min": lowest mean held-out RMSE; "1se": the strongest within one SE of it


@dataclass(frozen=True)
class CorpusSpec:
    manifest: Path | None = None
    files: tuple[Path, ...] = ()
    labels: tuple[Path, ...] = ()
    file_column: str = "file"  # manifest column holding the data file
    label_map: str | None = None  # a label-map name or path; None: labels are model phonemes
    role_map: dict[str, Any] | None = None  # role -> marker/sensor name; EMA: "axes" = {vertical, anterior}
    select: dict[str, tuple[str, ...]] = field(default_factory=dict)  # manifest column -> kept values
    limit: int | None = None  # keep only the first N trials (quick looks)


@dataclass(frozen=True)
class FitSpec:
    path: Path  # the spec file (errors and relative paths refer to it)
    name: str
    corpus: CorpusSpec
    channels: tuple[str, ...]
    variant: str = "modified"
    reference_phoneme: str = "a"
    apex_fraction: float = default("apex_fraction")
    edge_extent: float = default("edge_extent")
    # the rate-aware options of docs/MODEL.md §2.1 (defaults: today's model)
    dominance: str = SPEC_MODEL_DEFAULTS["dominance"]
    plateau_fraction: float = default("plateau_fraction")
    handover: bool = SPEC_MODEL_DEFAULTS["handover"]
    beta: float = default("beta")
    fit_beta: bool = False
    beta_bounds: tuple[float, float] = DEFAULT_BETA_BOUNDS
    free: tuple[str, ...] = DEFAULT_FREE
    # free parameters with one value per channel, shared by every phoneme where they are free
    shared: tuple[str, ...] = DEFAULT_SHARED
    # sd (mm) of a Gaussian prior drawing every free target toward the mean of the channel over its
    # phoneme's segments in the fitted data (the step model's value); None: no such prior
    target_prior: float | None = DEFAULT_TARGET_PRIOR
    start_table: Path | None = None  # "from table": start values from a ParameterTable JSON
    start: dict[str, float] = field(default_factory=lambda: dict(DEFAULT_START))
    # Gaussian priors (penalties in least squares): "parameter" (every phoneme) or "phoneme.parameter"
    # (or "beta") -> (mean, sd, on log values); weighed against prior_noise (mm)
    priors: dict[str, tuple[float, float, bool]] = field(default_factory=dict)
    prior_noise: float = 1.0
    offsets: str | float = "none"  # per-utterance offsets in least squares: "none", "free" or their sd (mm)
    # several speakers in one fit: "none", "offset" (a_s + F), "offset_scale" (a_s + b_s·F) or
    # "targets" (own targets per speaker), the speaker read from the manifest column speaker_column;
    # shared dynamics
    speakers: str = "none"
    speaker_column: str = "speaker"
    start_given: frozenset[str] = frozenset()  # the [parameters.start] keys the spec gives (checked against bounds)
    bounds: dict[str, tuple[float, float]] = field(default_factory=lambda: dict(DEFAULT_FIT_BOUNDS))
    channel_bounds: dict[str, dict[str, tuple[float, float]]] = field(default_factory=dict)
    target_margin: float = 5.0  # mm beyond the observed range for the default target box
    overrides: tuple[Override, ...] = ()
    ties: tuple[Tie, ...] = ()
    shrinks: tuple[Shrink, ...] = ()
    choose: Choose | None = None
    engine: str = "scipy"
    engine_options: dict[str, Any] = field(default_factory=dict)
    staging: bool = True
    stages: tuple[tuple[str, ...], ...] = DEFAULT_STAGES
    # [fit]: global estimation by multi-start (coartic.fit.multistart); starts = 1 is one local fit
    # from [parameters.start]
    starts: int = DEFAULT_STARTS
    seed: int = 0
    probe: int = DEFAULT_PROBE
    keep: int | None = None  # starts continued after the probe (None: multistart.default_keep)
    include_start: bool = True  # start 0 is [parameters.start] (always continued)
    max_gap: float = 0.05  # s: gaps up to this are interpolated by the reader, longer ones masked
    validate_group: str | None = None  # k-fold validation by this grouping (VALIDATE_GROUPS)
    validate_folds: int | None = None  # None: one fold per group (leave one group out)
    holdout_repetition: int | None = 5
    train_rate: str | None = "normal"
    test_rate: str | None = "fast"

    def with_options(self, **changes: Any) -> FitSpec:
        return replace(self, **changes)

    def channel_settings(self, channel: str, beta: float | None = None) -> ChannelSettings:
        """The settings a fit of ``channel`` uses and writes into its table (``beta``: the fitted
        value; default the spec's). The fit's model options are made from them
        (``coartic.model.channel_options``), so a table evaluates as it was fitted."""
        return ChannelSettings(reference_phoneme=self.reference_phoneme, beta=self.beta if beta is None else beta,
                               edge_extent=self.edge_extent, apex_fraction=self.apex_fraction,
                               dominance=self.dominance, plateau_fraction=self.plateau_fraction,
                               handover=self.handover)


def _count(table: dict[str, Any], key: str, default: int | None, low: int, path: Path) -> Any:
    """An integer >= ``low`` under ``[fit] key`` (or the default)."""
    v = table.get(key, default)
    if v is not None and (isinstance(v, bool) or not isinstance(v, int) or v < low):
        raise _err(path, f"fit.{key}", f"expected an integer >= {low}, got {v!r}")
    return v


def _err(path: Path, key: str, msg: str) -> SpecError:
    return SpecError.at(path, key, msg)


def _array_of_tables(raw: dict[str, Any], name: str, path: Path) -> list[tuple[str, dict[str, Any]]]:
    """The spec's [[name]] tables, each with the key its errors are named by ("tie #2")."""
    items = raw.get(name, [])
    if not isinstance(items, list):
        raise _err(path, name, f"expected [[{name}]] tables")
    out = []
    for i, item in enumerate(items):
        key = f"{name} #{i + 1}"
        if not isinstance(item, dict):
            raise _err(path, key, f"expected a table, got {item!r}")
        out.append((key, item))
    return out


def _take(d: dict[str, Any], path: Path, section: str, allowed: set[str]) -> None:
    unknown = sorted(set(d) - allowed)
    if unknown:
        raise _err(path, section, f"unknown key(s) {unknown}; allowed: {sorted(allowed)}")


def _str_list(v: Any, path: Path, key: str) -> tuple[str, ...]:
    if isinstance(v, str):
        return (v,)
    if not isinstance(v, list) or not all(isinstance(s, str) for s in v):
        raise _err(path, key, f"expected a list of strings, got {v!r}")
    return tuple(v)


def _float(v: Any, path: Path, key: str) -> float:
    # TOML has nan: refused here, once, so that no comparison downstream lets it through
    if isinstance(v, bool) or not isinstance(v, (int, float)) or math.isnan(v):
        raise _err(path, key, f"expected a number, got {v!r}")
    return float(v)


def _setting(m: dict[str, Any], name: str, path: Path) -> Any:
    """A ``[model]`` channel setting (coartic.settings): its default when absent, else checked."""
    setting = CHANNEL_SETTINGS[name]
    v = m.get(name, SPEC_MODEL_DEFAULTS.get(name, setting.default))
    problem = setting.problem(v)
    if problem is not None:
        raise _err(path, f"model.{name}", f"{name} = {v!r} {problem} ({setting.meaning})")
    return v if setting.flag or setting.choices else float(v)


def _param_names(names: tuple[str, ...], path: Path, key: str, allow_beta: bool = False) -> tuple[str, ...]:
    allowed = PARAMETERS + (("beta",) if allow_beta else ())
    for n in names:
        if n not in allowed:
            raise _err(path, key, f"unknown parameter {n!r}; known: {', '.join(allowed)}")
    return names


def _param_values(d: Any, path: Path, key: str, phonemes: tuple[str, ...] = ()) -> dict[str, float]:
    """``parameter = value`` pairs (starts, fixed values), each in its parameter's model domain
    (MODEL.md §1); errors name the key and, for an ``[[override]]``, its phonemes."""
    if not isinstance(d, dict):
        raise _err(path, key, f"expected a table of parameter = value, got {d!r}")
    _param_names(tuple(d), path, key)
    out = {k: _float(v, path, f"{key}.{k}") for k, v in d.items()}
    for k, v in out.items():
        problem = domain_problem(k, v)
        if problem is not None:
            whose = f" (of {', '.join(phonemes)})" if phonemes else ""
            raise _err(path, f"{key}.{k}", f"{k} = {v:g}{whose} {problem}, the model's domain of {k}")
    return out


def _bounds(d: Any, path: Path, key: str) -> dict[str, tuple[float, float]]:
    if not isinstance(d, dict):
        raise _err(path, key, f"expected a table of parameter = [low, high], got {d!r}")
    out: dict[str, tuple[float, float]] = {}
    for k, v in d.items():
        if isinstance(v, dict):
            continue  # a per-channel sub-table, read by the caller
        _param_names((k,), path, key)
        if not isinstance(v, list) or len(v) != 2:
            raise _err(path, f"{key}.{k}", f"expected [low, high], got {v!r}")
        lo, hi = _float(v[0], path, f"{key}.{k}"), _float(v[1], path, f"{key}.{k}")
        if not lo < hi:
            raise _err(path, f"{key}.{k}", f"low {lo} must be below high {hi}")
        out[k] = (lo, hi)
    return out


def _channels(names: tuple[str, ...], path: Path, key: str) -> tuple[str, ...]:
    for c in names:
        if c not in ALL_CHANNELS:
            raise _err(path, key, f"unknown channel {c!r}; known: {', '.join(ALL_CHANNELS)}")
    return names


def synth_hint(manifest: Path) -> str:
    """What to run when ``manifest`` is absent, naming that very corpus (the session and the
    speakers' corpus are both made by ``coartic corpus synth``, which one is not known here)."""
    return (f" (if it is a synthetic corpus: `coartic corpus synth {manifest.parent}`, with `--speakers N` for "
            "several speakers)")


def _path(base: Path, v: Any, key: str, spec_path: Path) -> Path:
    if not isinstance(v, str) or not v:
        raise _err(spec_path, key, f"expected a path string, got {v!r}")
    p = Path(v)
    return p if p.is_absolute() else (base / p)


LOG_SCALE_PARAMETERS = ("alpha", "theta_bw", "theta_fw", "psi", "beta")


def _priors(d: Any, path: Path) -> dict[str, tuple[float, float, bool]]:
    """``[parameters.prior]``: key "parameter", "phoneme.parameter" or "beta"; value [mean, sd] on
    the natural value, or { mean = m, sd = s, scale = "log" } on its logarithm (m its median)."""
    if not isinstance(d, dict):
        raise _err(path, "parameters.prior", f"expected a table \"phoneme.parameter\" = [mean, sd], got {d!r}")
    out: dict[str, tuple[float, float, bool]] = {}
    for key, v in d.items():
        where = f"parameters.prior.{key}"
        name = key.rpartition(".")[2]
        _param_names((name,), path, where, allow_beta=True)
        if isinstance(v, list) and len(v) == 2:
            mean, sd, scale = _float(v[0], path, where), _float(v[1], path, where), "natural"
        elif isinstance(v, dict):
            _take(v, path, where, {"mean", "sd", "scale"})
            if "mean" not in v or "sd" not in v:
                raise _err(path, where, "needs mean and sd")
            mean, sd, scale = _float(v["mean"], path, where), _float(v["sd"], path, where), v.get("scale", "natural")
        else:
            raise _err(path, where, f"expected [mean, sd] or {{ mean, sd, scale }}, got {v!r}")
        if scale not in ("natural", "log"):
            raise _err(path, where, f"scale = {scale!r}: expected \"natural\" or \"log\"")
        if not (math.isfinite(mean) and math.isfinite(sd) and sd > 0):
            raise _err(path, where, f"needs a finite mean and a positive sd, got mean {mean}, sd {sd}")
        if scale == "log" and (name not in LOG_SCALE_PARAMETERS or mean <= 0):
            raise _err(path, where, f"a log-scale prior needs a positive parameter ({', '.join(LOG_SCALE_PARAMETERS)}) "
                       f"and a positive mean, got {name} with mean {mean}")
        out[key] = (mean, sd, scale == "log")
    return out


def _target_prior(v: Any, path: Path) -> float | None:
    """``[parameters] target_prior``: "none", or the prior's sd in mm (a positive number)."""
    if v == "none":
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v > 0):
        raise _err(path, "parameters.target_prior", f"{v!r}: expected \"none\" or a positive number (the sd in mm "
                   "of every target around its phoneme's mean in the data)")
    return float(v)


def _shrinks(raw: dict[str, Any], path: Path) -> tuple[Shrink, ...]:
    """``[[shrink]]`` tables: phonemes (a class of two or more), parameters, sd, scale, channels."""
    out = []
    for key, t in _array_of_tables(raw, "shrink", path):
        _take(t, path, key, {"phonemes", "parameters", "sd", "scale", "channels"})
        if "phonemes" not in t or "parameters" not in t or "sd" not in t:
            raise _err(path, key, "needs phonemes = [...], parameters = [...] and sd = ...")
        ph = _str_list(t["phonemes"], path, f"{key}.phonemes")
        if len(set(ph)) < 2 or len(set(ph)) != len(ph):
            raise _err(path, f"{key}.phonemes", f"a class needs two distinct phonemes or more, got {list(ph)}")
        par = _param_names(_str_list(t["parameters"], path, f"{key}.parameters"), path, f"{key}.parameters")
        if not par or len(set(par)) != len(par):
            raise _err(path, f"{key}.parameters", f"expected distinct parameters, got {list(par)}")
        sd = _float(t["sd"], path, f"{key}.sd")
        if not (sd > 0 and math.isfinite(sd)):
            raise _err(path, f"{key}.sd", f"{sd} must be a positive number")
        scale = t.get("scale", "natural")
        if scale not in ("natural", "log"):
            raise _err(path, f"{key}.scale", f"{scale!r}: expected \"natural\" or \"log\"")
        if scale == "log":
            bad = [p for p in par if p not in LOG_SCALE_PARAMETERS]
            if bad:
                raise _err(path, f"{key}.scale", f"log scale needs positive parameters ({', '.join(LOG_SCALE_PARAMETERS[:-1])}), "
                           f"not {bad}: shrink those in another [[shrink]] on the natural scale")
        ch = _channels(_str_list(t["channels"], path, f"{key}.channels"), path, f"{key}.channels") \
            if "channels" in t else None
        out.append(Shrink(ph, par, sd, scale == "log", ch, key))
    return tuple(out)


def _choose(c: Any, path: Path, shrinks: tuple[Shrink, ...]) -> Choose | None:
    """``[choose]``: key, values (the grid), group, folds, rule."""
    if c is None:
        return None
    if not isinstance(c, dict):
        raise _err(path, "choose", f"expected a table, got {c!r}")
    _take(c, path, "choose", {"key", "values", "group", "folds", "rule"})
    if "key" not in c or "values" not in c:
        raise _err(path, "choose", "needs key = \"shrink.sd\" (or another setting) and values = [...]")
    return make_choose(path, c["key"], c["values"], c.get("group", "utterance"), c.get("folds", 5),
                       c.get("rule", "1se"), shrinks, "choose")


def make_choose(path: Path, key: Any, values: Any, group: Any, folds: Any, rule: Any,
                shrinks: tuple[Shrink, ...], where: str) -> Choose:
    """A checked ``Choose`` (from ``[choose]`` or ``coartic fit --choose``); errors name ``where``."""
    if not isinstance(key, str):
        raise _err(path, f"{where}.key", f"expected a setting name, got {key!r}")
    base = choose_base(key)
    if base is None:
        raise _err(path, f"{where}.key", f"{key!r}: not a setting cross-validation can choose (known: "
                   f"{', '.join(CHOOSABLE)}, or \"shrink #N.sd\" for one [[shrink]])")
    if base == "shrink.sd":
        if not shrinks:
            raise _err(path, f"{where}.key", f"{key!r}: the spec has no [[shrink]] table")
        if key != "shrink.sd" and not any(s.key == key[: -len(".sd")] for s in shrinks):
            raise _err(path, f"{where}.key", f"{key!r}: no such table (the spec has {len(shrinks)} [[shrink]])")
    if not isinstance(values, list) or len(values) < 2:
        raise _err(path, f"{where}.values", f"expected a list of two values or more, got {values!r}")
    vals = tuple(_float(v, path, f"{where}.values") for v in values)
    if len(set(vals)) != len(vals):
        raise _err(path, f"{where}.values", f"repeated values in {list(vals)}")
    low = 0.0
    if any(not math.isfinite(v) or v <= low for v in vals) and base != "plateau_fraction":
        raise _err(path, f"{where}.values", f"{key} takes positive numbers, got {list(vals)}")
    if base == "plateau_fraction" and any(CHANNEL_SETTINGS[base].problem(v) for v in vals):
        raise _err(path, f"{where}.values", f"plateau_fraction takes values in {CHANNEL_SETTINGS[base].allowed}, "
                   f"got {list(vals)}")
    if group not in VALIDATE_GROUPS:
        raise _err(path, f"{where}.group", f"{group!r}: expected one of {', '.join(VALIDATE_GROUPS)}")
    if isinstance(folds, bool) or not isinstance(folds, int) or folds < 2:
        raise _err(path, f"{where}.folds", f"expected an integer >= 2, got {folds!r}")
    if rule not in CHOOSE_RULES:
        raise _err(path, f"{where}.rule", f"{rule!r}: expected \"min\" or \"1se\"")
    if rule == "1se" and CHOOSABLE[base] == 0:
        raise _err(path, f"{where}.rule", f"\"1se\" needs a regularisation strength (shrink.sd, prior_noise, target_prior); "
                   f"{key} has no stronger end: use rule = \"min\"")
    return Choose(key, tuple(sorted(vals)), str(group), int(folds), str(rule))


def parse_grid(option: str, text: str, example: str = "") -> tuple[str, list[str]]:
    """``KEY=V1,V2,...`` of a command-line option (``--vary``, ``--choose``): the key and the values
    as given (each command converts them), or a SpecError naming the option."""
    key, sep, values = text.partition("=")
    if not sep or not key.strip() or not values.strip():
        raise SpecError(f"{option} {text!r}: expected KEY=V1,V2,...{f' (e.g. {example})' if example else ''}")
    grid = [v.strip() for v in values.split(",")]
    if not all(grid):
        raise SpecError(f"{option} {text!r}: an empty value between commas")
    return key.strip(), grid


def choose_base(key: str) -> str | None:
    """The CHOOSABLE entry a key belongs to ("shrink #2.sd" -> "shrink.sd"), or None."""
    if key in CHOOSABLE:
        return key
    if key.startswith("shrink #") and key.endswith(".sd") and key[len("shrink #"):-len(".sd")].isdigit():
        return "shrink.sd"
    return None


def read_document(path: Path) -> dict[str, Any]:
    """The TOML document of a spec file, or a SpecError naming the file."""
    try:
        return tomllib.loads(read_text(path, "fit spec"))
    except FileNotFoundError:
        raise SpecError(f"{path}: no such fit spec") from None
    except IsADirectoryError:
        raise SpecError(f"{path}: is a directory, not a fit spec (.toml) file") from None
    except TextDecodeError as e:
        raise SpecError(str(e)) from None
    except tomllib.TOMLDecodeError as e:
        raise SpecError(f"{path}: not valid TOML: {e}") from None


def load_spec(path: str | Path) -> FitSpec:
    """Read and check a fit spec. Raises SpecError naming the file and key on any problem."""
    path = Path(path)
    return parse_spec(read_document(path), path)


def parse_spec(raw: dict[str, Any], path: Path) -> FitSpec:
    """Build a FitSpec from an already parsed TOML document (``path`` locates relative paths)."""
    base = path.parent
    # [mcmc] belongs to coartic.mcmc (docs/MCMC.md): one spec file serves both commands.
    _take(raw, path, "top level", {"name", "corpus", "model", "parameters", "override", "tie", "shrink",
                                   "choose", "engine", "staging", "gaps", "validate", "mcmc", "fit"})
    name = raw.get("name", path.stem)

    c = raw.get("corpus")
    if not isinstance(c, dict):
        raise _err(path, "corpus", "missing: give a manifest or a list of files and labels")
    _take(c, path, "corpus", {"manifest", "files", "labels", "file_column", "label_map", "role_map",
                              "select", "limit"})
    manifest = _path(base, c["manifest"], "corpus.manifest", path) if "manifest" in c else None
    files = tuple(_path(base, f, "corpus.files", path) for f in _str_list(c.get("files", []), path, "corpus.files"))
    labels = tuple(_path(base, f, "corpus.labels", path) for f in _str_list(c.get("labels", []), path, "corpus.labels"))
    if manifest is None and not files:
        raise _err(path, "corpus", "give either manifest = 'path/manifest.csv' or files = [...]")
    if manifest is not None and files:
        raise _err(path, "corpus", "give manifest or files, not both")
    if files and len(labels) != len(files):
        raise _err(path, "corpus.labels", f"{len(labels)} label files for {len(files)} data files")
    label_map = c.get("label_map")
    if label_map is not None and not isinstance(label_map, str):
        raise _err(path, "corpus.label_map", f"expected a name or path, got {label_map!r}")
    if label_map is not None and ("/" in label_map or label_map.endswith((".tsv", ".json"))):
        label_map = str(_path(base, label_map, "corpus.label_map", path))
    role_map = c.get("role_map")
    if role_map is not None:
        if not isinstance(role_map, dict) or not all(
                isinstance(v, str) or (k == "axes" and isinstance(v, dict)) for k, v in role_map.items()):
            raise _err(path, "corpus.role_map", "expected a table role = 'sensor' (and for EMA "
                       f"axes = {{ vertical = '+z', anterior = '-y' }}), got {role_map!r}")
        try:  # the role map's own checks (roles, axes, one marker per role), named by the spec key
            RoleMap.from_dict(role_map, "role map")
        except DataError as bad:
            raise _err(path, "corpus.role_map", str(bad)) from None
    select_raw = c.get("select", {})
    if not isinstance(select_raw, dict):
        raise _err(path, "corpus.select", f"expected a table column = [values], got {select_raw!r}")
    select = {k: tuple(str(x) for x in (v if isinstance(v, list) else [v])) for k, v in select_raw.items()}
    limit = c.get("limit")
    if limit is not None and (isinstance(limit, bool) or not isinstance(limit, int) or limit < 1):
        raise _err(path, "corpus.limit", f"expected a positive integer, got {limit!r}")
    corpus = CorpusSpec(manifest=manifest, files=files, labels=labels,
                        file_column=str(c.get("file_column", "file")), label_map=label_map,
                        role_map=role_map, select=select, limit=limit)

    m = raw.get("model", {})
    _take(m, path, "model", {"variant", "channels", "reference_phoneme", "apex_fraction", "edge_extent",
                             "beta", "fit_beta", "beta_bounds", "offsets", "dominance", "plateau_fraction",
                             "handover", "speakers", "speaker_column"})
    speakers = m.get("speakers", "none")
    if speakers not in ("none", "offset", "offset_scale", "targets"):
        raise _err(path, "model.speakers",
                   f"{speakers!r}: expected \"none\", \"offset\", \"offset_scale\" or \"targets\"")
    speaker_column = m.get("speaker_column", "speaker")
    if not isinstance(speaker_column, str) or not speaker_column:
        raise _err(path, "model.speaker_column", f"{speaker_column!r}: expected a manifest column name")
    offsets = m.get("offsets", "none")
    if isinstance(offsets, bool) or not (offsets in ("none", "free") or (
            isinstance(offsets, (int, float)) and math.isfinite(offsets) and offsets > 0)):
        raise _err(path, "model.offsets", f"{offsets!r}: expected \"none\", \"free\" or a positive number "
                   "(the offsets' sd in mm)")
    if speakers != "none" and offsets != "none":
        raise _err(path, "model.speakers", "cannot be combined with [model] offsets yet: choose one")
    variant = m.get("variant", "modified")
    if variant not in VARIANTS:
        raise _err(path, "model.variant", f"{variant!r}: expected one of {VARIANTS}")
    channels = _channels(_str_list(m.get("channels", list(CHANNELS)), path, "model.channels"), path, "model.channels")
    if not channels:
        raise _err(path, "model.channels", "no channel to fit")
    beta_bounds = DEFAULT_BETA_BOUNDS
    if "beta_bounds" in m:
        bb = m["beta_bounds"]
        if not isinstance(bb, list) or len(bb) != 2:
            raise _err(path, "model.beta_bounds", f"expected [low, high], got {bb!r}")
        beta_bounds = (_float(bb[0], path, "model.beta_bounds"), _float(bb[1], path, "model.beta_bounds"))
        if not 0.0 <= beta_bounds[0] < beta_bounds[1]:
            raise _err(path, "model.beta_bounds", f"need 0 <= low < high, got {beta_bounds}")
    apex = _setting(m, "apex_fraction", path)
    edge = _setting(m, "edge_extent", path)
    fit_beta = m.get("fit_beta", False)
    if not isinstance(fit_beta, bool):
        raise _err(path, "model.fit_beta", f"expected true or false, got {fit_beta!r}")
    dominance = _setting(m, "dominance", path)
    plateau = _setting(m, "plateau_fraction", path)
    handover = _setting(m, "handover", path)

    beta = _setting(m, "beta", path)

    p = raw.get("parameters", {})
    _take(p, path, "parameters", {"free", "shared", "start", "start_table", "bounds", "target_margin", "prior",
                                  "prior_noise", "target_prior"})
    free = _param_names(_str_list(p.get("free", list(DEFAULT_FREE)), path, "parameters.free"), path, "parameters.free")
    # the shared dynamics belong to the default freedom: a spec that lists its own free set keeps
    # per-phoneme values unless it says shared = [...] too
    shared = _param_names(_str_list(p.get("shared", list(DEFAULT_SHARED) if "free" not in p else []), path,
                                    "parameters.shared"), path, "parameters.shared")
    if "target" in shared:
        raise _err(path, "parameters.shared", "target cannot be shared: one target for every phoneme is the "
                   "constant model")
    target_prior = _target_prior(p.get("target_prior", DEFAULT_TARGET_PRIOR if DEFAULT_TARGET_PRIOR else "none"), path)
    start = dict(DEFAULT_START)
    start_given = _param_values(p.get("start", {}), path, "parameters.start")
    start.update(start_given)
    start_table = _path(base, p["start_table"], "parameters.start_table", path) if "start_table" in p else None
    bounds_raw = p.get("bounds", {})
    bounds = dict(DEFAULT_FIT_BOUNDS)
    bounds.update(_bounds(bounds_raw, path, "parameters.bounds"))
    channel_bounds: dict[str, dict[str, tuple[float, float]]] = {}
    for k, v in bounds_raw.items():
        if isinstance(v, dict):
            _channels((k,), path, f"parameters.bounds.{k}")
            channel_bounds[k] = _bounds(v, path, f"parameters.bounds.{k}")
    for k, (lo, hi) in bounds.items():
        if k in ("alpha", "theta_bw", "theta_fw", "psi") and lo <= 0:
            raise _err(path, f"parameters.bounds.{k}", f"low {lo} must be > 0 (fitted on a log scale)")
    margin = _float(p.get("target_margin", 5.0), path, "parameters.target_margin")
    priors = _priors(p.get("prior", {}), path)
    prior_noise = _float(p.get("prior_noise", 1.0), path, "parameters.prior_noise")
    if not (prior_noise > 0 and math.isfinite(prior_noise)):
        raise _err(path, "parameters.prior_noise", f"{prior_noise} must be a positive number (mm)")

    overrides: list[Override] = []
    for key, table in _array_of_tables(raw, "override", path):
        _take(table, path, key, {"phonemes", "channels", "fixed", "free", "start", "bounds"})
        if "phonemes" not in table:
            raise _err(path, key, "missing phonemes = [...]")
        chans = _channels(_str_list(table["channels"], path, f"{key}.channels"), path, f"{key}.channels") \
            if "channels" in table else None
        o_phonemes = _str_list(table["phonemes"], path, f"{key}.phonemes")
        overrides.append(Override(
            phonemes=o_phonemes, channels=chans,
            fixed=_param_values(table.get("fixed", {}), path, f"{key}.fixed", o_phonemes),
            free=_param_names(_str_list(table.get("free", []), path, f"{key}.free"), path, f"{key}.free"),
            start=_param_values(table.get("start", {}), path, f"{key}.start", o_phonemes),
            bounds=_bounds(table.get("bounds", {}), path, f"{key}.bounds")))

    reference = str(m.get("reference_phoneme", "a"))
    ties: list[Tie] = []
    for key, t in _array_of_tables(raw, "tie", path):
        _take(t, path, key, {"phonemes", "parameters", "channels"})
        if "phonemes" not in t or "parameters" not in t:
            raise _err(path, key, "needs phonemes = [...] and parameters = [...]")
        tph = _str_list(t["phonemes"], path, f"{key}.phonemes")
        if len(set(tph)) < 2:
            raise _err(path, f"{key}.phonemes", f"a tie needs two phonemes or more, got {list(tph)}")
        tpar = _param_names(_str_list(t["parameters"], path, f"{key}.parameters"), path, f"{key}.parameters")
        if reference in tph and "alpha" in tpar:
            raise _err(path, key, f"ties alpha of the reference phoneme {reference!r}, which is fixed at 1")
        tch = _channels(_str_list(t["channels"], path, f"{key}.channels"), path, f"{key}.channels") \
            if "channels" in t else None
        ties.append(Tie(tph, tpar, tch))
    shrinks = _shrinks(raw, path)
    tied = {q for t in ties for q in t.parameters} & set(shared)
    if tied:
        raise _err(path, "parameters.shared", f"{', '.join(sorted(tied))} is both shared by every phoneme and in a "
                   "[[tie]]: one or the other")
    freed = set(free) | {n for o in overrides for n in o.free}
    if set(shared) - freed:
        raise _err(path, "parameters.shared", f"{', '.join(sorted(set(shared) - freed))} is not free ([parameters] "
                   "free or an [[override]] free): sharing a fixed value would do nothing")
    for i, o in enumerate(overrides):
        # alpha is scale-free: the reference phoneme's is 1 by definition (MODEL.md §1)
        if reference in o.phonemes and ("alpha" in o.free or "alpha" in o.start or "alpha" in o.bounds
                                        or o.fixed.get("alpha", 1.0) != 1.0):
            raise _err(path, f"override #{i + 1}", f"sets alpha of the reference phoneme {reference!r}, which is "
                       "fixed at 1 (alpha is scale-free); choose another [model] reference_phoneme to fit it")

    e = raw.get("engine", {})
    _take(e, path, "engine", {"name", "options"})
    engine = e.get("name", "scipy")
    if engine not in ENGINES:
        raise _err(path, "engine.name", f"{engine!r}: unknown engine ({', '.join(ENGINES)})")
    engine_options = e.get("options", {})
    if not isinstance(engine_options, dict):
        raise _err(path, "engine.options", f"expected a table, got {engine_options!r}")

    s = raw.get("staging", {})
    _take(s, path, "staging", {"enabled", "stages"})
    staging = s.get("enabled", True)
    if not isinstance(staging, bool):
        raise _err(path, "staging.enabled", f"expected true or false, got {staging!r}")
    stages = DEFAULT_STAGES
    if "stages" in s:
        if not isinstance(s["stages"], list) or not s["stages"]:
            raise _err(path, "staging.stages", "expected a list of parameter lists")
        stages = tuple(_param_names(_str_list(st, path, "staging.stages"), path, "staging.stages", allow_beta=True)
                       for st in s["stages"])

    fit = raw.get("fit", {})
    if not isinstance(fit, dict):
        raise _err(path, "fit", f"expected a table, got {fit!r}")
    _take(fit, path, "fit", {"starts", "seed", "probe", "keep", "include_start"})
    include_start = fit.get("include_start", True)
    if not isinstance(include_start, bool):
        raise _err(path, "fit.include_start", f"expected true or false, got {include_start!r}")
    starts, seed, probe = (_count(fit, key, default, low, path) for key, default, low in
                           (("starts", DEFAULT_STARTS, 1), ("seed", 0, 0), ("probe", DEFAULT_PROBE, 1)))
    keep = _count(fit, "keep", None, 1, path)
    if keep is not None and starts > 1 and keep > starts:
        raise _err(path, "fit.keep", f"{keep}: more than the {starts} starts")

    g = raw.get("gaps", {})
    _take(g, path, "gaps", {"max_gap"})
    max_gap = _float(g.get("max_gap", 0.05), path, "gaps.max_gap")

    v = raw.get("validate", {})
    _take(v, path, "validate", {"holdout_repetition", "train_rate", "test_rate", "group", "folds"})
    hold = v.get("holdout_repetition", 5)
    if hold is not None and (isinstance(hold, bool) or not isinstance(hold, int)):
        raise _err(path, "validate.holdout_repetition", f"expected an integer, got {hold!r}")
    group = v.get("group")
    if group is not None and group not in VALIDATE_GROUPS:
        raise _err(path, "validate.group", f"{group!r}: expected one of {', '.join(VALIDATE_GROUPS)}")
    folds = v.get("folds")
    if folds is not None and (isinstance(folds, bool) or not isinstance(folds, int) or folds < 2):
        raise _err(path, "validate.folds", f"expected an integer >= 2, got {folds!r}")
    if folds is not None and group is None:
        raise _err(path, "validate.folds", "needs group = \"utterance\" (or sentence, rate, speaker, repetition)")

    choose = _choose(raw.get("choose"), path, shrinks)

    return FitSpec(
        path=path, name=str(name), corpus=corpus, channels=channels, variant=variant,
        reference_phoneme=reference, apex_fraction=apex, edge_extent=edge, dominance=dominance,
        plateau_fraction=plateau, handover=handover,
        beta=beta, fit_beta=fit_beta, beta_bounds=beta_bounds,
        free=free, shared=shared, target_prior=target_prior, start_table=start_table, start=start, start_given=frozenset(start_given), bounds=bounds,
        priors=priors, prior_noise=prior_noise, offsets=offsets if isinstance(offsets, str) else float(offsets),
        speakers=str(speakers), speaker_column=speaker_column, channel_bounds=channel_bounds,
        target_margin=margin, overrides=tuple(overrides), ties=tuple(ties), shrinks=shrinks, choose=choose,
        engine=engine, engine_options=dict(engine_options),
        staging=staging, stages=stages, starts=starts, seed=seed, probe=probe, keep=keep, include_start=include_start,
        max_gap=max_gap, holdout_repetition=hold, validate_group=group,
        validate_folds=folds,
        train_rate=v.get("train_rate", "normal"), test_rate=v.get("test_rate", "fast"))
