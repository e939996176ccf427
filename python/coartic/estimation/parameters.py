"""The parameters of one channel's fit, lmfit-style: per phoneme and parameter its value, whether it
is free, its bounds, its prior and (after a fit) its standard error.

``ParameterSet.from_settings`` is where the settings (``coartic.estimation.settings``, a fit spec's
or built in Python) become numbers (the one place: least squares, MCMC and the report all start
from it); ``packing()`` gives the engines' view (``coartic.estimation.packing.
Packing``: the free entries as an internal vector x), and ``ChannelFit.parameters`` the fitted set
with standard errors, which ``parameters.csv`` and ``fit_report.txt`` print.

A setting is honoured or refused, never dropped: a global ``[parameters.bounds]
target`` replaces the data range, a ``target`` start replaces the data targets, and a start the
spec gives outside its bounds is an error naming the key (a default start outside bounds the spec
narrowed starts on the nearest bound).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any, Iterator, Mapping

import numpy as np
from numpy.typing import NDArray

from coartic.estimation.packing import Packing, Prior, tie_group
from coartic.estimation.target_prior import target_priors
from coartic.errors import SpecError
from coartic.pauses import EDGE_TIED, FINAL_PAUSE, MEDIAL_ALPHA, MEDIAL_PAUSE
from coartic.table import N_PARAMS, PARAMETERS, PAUSE


if TYPE_CHECKING:  # annotations only
    from coartic.estimation.data import ChannelData
    from coartic.estimation.settings import EstimationSettings

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
def psd_pseudo_inverse(a: FloatArray, rtol: float = 1e-10) -> tuple[FloatArray, FloatArray, BoolArray]:
    """The pseudo-inverse of a symmetric positive semi-definite matrix (JᵀJ, a Gauss–Newton
    Hessian), dropping eigen-directions below ``rtol`` × the largest eigenvalue (the directions
    the data do not identify); also the eigenvectors and which of them were kept."""
    w, v = np.linalg.eigh(a)
    keep = w > rtol * max(float(w.max()) if w.size else 0.0, 1e-300)
    return (v[:, keep] / w[keep]) @ v[:, keep].T, v, keep


# Why a free parameter sits on a bound (coartic.estimation.bounds computes a BoundNote for each).
CATEGORIES: tuple[str, ...] = ("domain", "active", "optimal", "insensitive", "unexplained")
CATEGORY_TITLES: dict[str, str] = {
    "domain": "model domain — by design",
    "active": "active — the data pull beyond the bound",
    "optimal": "not binding — a wider box would not change the fit",
    "insensitive": "insensitive — not constrained by the data",
    "unexplained": "UNEXPLAINED — the fit is not held at this bound",
}

@dataclass(frozen=True)
class BoundNote:
    """The explanation of one free parameter at a bound (``parameters.csv``, ``summary.json``)."""

    name: str
    phoneme: str
    parameter: str
    value: float
    side: str  # "lower" | "upper"
    bound: float
    source: str  # where the box comes from: "model domain …", a spec key, or the defaults
    category: str  # one of CATEGORIES
    gradient: float  # d(SSE)/dx at the fit, x the fitted coordinate (ln value for log-fitted parameters)
    gradient_of: str  # "ln theta_bw" or "k_r": what x is
    gain_held_chi2: float  # best measured SSE decrease past the bound, others held (Δχ²); NaN: not probed
    held_value: float  # the value past the bound where it was measured
    gain_gn_chi2: float  # Gauss–Newton estimate with the interior parameters re-adjusted (Δχ²)
    gain_gn_measured_chi2: float  # the model evaluated along that direction (Δχ²); NaN: not probed
    range_chi2: float  # the largest SSE rise over the whole box, others held (Δχ²)
    beyond_chi2: float  # the largest SSE rise past the bound, others held (Δχ²)
    rmse: float  # the channel's RMSE as fitted (mm)
    rmse_relaxed: float  # the RMSE with the best measured gain (mm)
    partner: str  # the free parameter most correlated with it ("" if none)
    partner_corr: float
    explanation: str  # the category's sentence, with numbers
    reading: str  # what the bound means for the model (MODEL.md names)
    shared_by: tuple[str, ...] = ()  # the phonemes that share this one value ([parameters] shared, [[tie]])

    @property
    def title(self) -> str:
        return CATEGORY_TITLES[self.category]

    def as_dict(self) -> dict[str, Any]:
        d = asdict(self)
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in d.items()}

    def short(self) -> str:
        """One line: name, value, side, category."""
        return f"{self.name} = {self.value:.4g} at its {self.side} bound {self.bound:.4g}: {self.title}"


# Parameters that the original model (eq. 1) ignores: never free there.
MODIFIED_ONLY: frozenset[str] = frozenset({"k_r", "sigma", "psi"})
BETA = "beta"


@dataclass(frozen=True)
class Parameter:
    """One entry: ``phoneme`` is ``"*"`` for the channel's β."""

    phoneme: str
    parameter: str
    value: float
    free: bool
    lower: float
    upper: float
    prior: Prior | None = None  # Gaussian (mean, sd, on log values or not)
    stderr: float = math.nan  # after a fit; NaN when fixed or not identified
    at_bound: bool = False
    identified: bool = True
    tied_to: str | None = None  # "phoneme.parameter" whose value this entry takes ([[tie]])
    bound_note: BoundNote | None = None  # why it is at a bound (coartic.estimation.bounds), after a fit
    shared_by: tuple[str, ...] = ()  # the phonemes whose one value this is ([parameters] shared, [[tie]]), carrier first

    @property
    def name(self) -> str:
        return BETA if self.parameter == BETA else f"{self.phoneme}.{self.parameter}"


class ParameterSet(Mapping[str, Parameter]):
    """Every parameter of one channel, keyed ``"phoneme.parameter"`` (and ``"beta"``).

    ``matrix`` (the values), ``free``, ``lower``, ``upper`` are ``[n_phonemes, 10]`` in
    ``PARAMETERS`` column order, rows in ``phonemes`` order.
    """

    def __init__(self, channel: str, phonemes: tuple[str, ...], matrix: FloatArray, free: BoolArray,
                 lower: FloatArray, upper: FloatArray, beta: float, beta_free: bool,
                 beta_bounds: tuple[float, float], priors: Mapping[str, Prior] | None = None,
                 stderr: Mapping[str, float] | None = None, at_bound: frozenset[str] = frozenset(),
                 unidentified: frozenset[str] = frozenset(),
                 origins: NDArray[np.object_] | None = None,
                 bound_notes: Mapping[str, BoundNote] | None = None) -> None:
        self.channel = channel
        self.phonemes = phonemes
        self.matrix, self.free, self.lower, self.upper = matrix, free, lower, upper
        self.beta, self.beta_free, self.beta_bounds = float(beta), bool(beta_free), beta_bounds
        self.priors = dict(priors or {})
        self.stderr = dict(stderr or {})
        self.at_bound, self.unidentified = at_bound, unidentified
        self.bound_notes = dict(bound_notes or {})
        # [n_phonemes, 10]: the spec key each value came from ("" for defaults, data, start
        # tables), so that a value the model refuses is named by its key (ChannelProblem.explain).
        self.origins = origins
        # (follower, leader) flat indices of [[tie]]d entries (Packing.ties)
        self.ties: tuple[tuple[int, int], ...] = ()
        # entries that are linear combinations of others (Packing.mixes: intensities' targets)
        self.mixes: tuple[tuple[int, tuple[tuple[int, float], ...]], ...] = ()
        # free name -> where its box comes from (a spec key or a default): Packing.bound_sources
        self.bound_sources: dict[str, str] = {}

    # ------------------------------------------------------------------ Mapping
    def _names(self) -> list[str]:
        return [f"{p}.{q}" for p in self.phonemes for q in PARAMETERS] + [BETA]

    def __iter__(self) -> Iterator[str]:
        return iter(self._names())

    def __len__(self) -> int:
        return len(self.phonemes) * N_PARAMS + 1

    def __getitem__(self, name: str) -> Parameter:
        def extra(nm: str) -> dict[str, object]:
            return {"prior": self.priors.get(nm), "stderr": self.stderr.get(nm, math.nan),
                    "at_bound": nm in self.at_bound, "identified": nm not in self.unidentified,
                    "bound_note": self.bound_notes.get(nm)}

        if name == BETA:
            lo, hi = self.beta_bounds if self.beta_free else (self.beta, self.beta)
            return Parameter("*", BETA, self.beta, self.beta_free, lo, hi, **extra(name))  # type: ignore[arg-type]
        phoneme, _, parameter = name.rpartition(".")
        if phoneme not in self.phonemes or parameter not in PARAMETERS:
            raise KeyError(name)
        i, k = self.phonemes.index(phoneme), PARAMETERS.index(parameter)
        leader = dict(self.ties).get(i * N_PARAMS + k)
        tied = None if leader is None else f"{self.phonemes[leader // N_PARAMS]}.{parameter}"
        info = extra(name) if tied is None else extra(tied) | {"prior": None}
        return Parameter(phoneme, parameter, float(self.matrix[i, k]), bool(self.free[i, k]),
                         float(self.lower[i, k]), float(self.upper[i, k]), tied_to=tied,
                         shared_by=tie_group(self.phonemes, self.ties, phoneme, parameter), **info)  # type: ignore[arg-type]

    @property
    def n_free(self) -> int:
        return int(self.free.sum()) + int(self.beta_free)

    # ------------------------------------------------------------------ building
    @classmethod
    def from_settings(cls, settings: EstimationSettings, data: ChannelData,
                      start: tuple[FloatArray, float] | None = None) -> ParameterSet:
        """Free set, bounds, priors and starting values of one channel from the settings.

        Targets start at the mean observed value at each phoneme's segment midpoints (a good start
        for the targets-first stage) unless the settings give a ``target`` start; the rest from
        ``[parameters.start]`` and the overrides, or from ``start`` (a start table's matrix and β).
        The reference phoneme has α fixed at 1 (MODEL.md §1: α is scale-free).
        """
        par, model, where = settings.parameters, settings.model, settings.source
        ch, phon = data.channel, data.phonemes
        n = len(phon)
        free = np.zeros((n, N_PARAMS), dtype=bool)
        for k, p in enumerate(PARAMETERS):
            free[:, k] = p in par.free and not (model.variant == "original" and p in MODIFIED_ONLY)
        lower = np.array([par.box(p)[0] for p in PARAMETERS])[None, :].repeat(n, 0)
        upper = np.array([par.box(p)[1] for p in PARAMETERS])[None, :].repeat(n, 0)
        # where each box comes from (coartic.estimation.bounds explains a parameter at a bound by it)
        source = np.array([par.bound_source(p) for p in PARAMETERS], dtype=object)[None, :].repeat(n, 0)
        if "target" not in par.bounds:  # no global target box: the data range, widened
            valid_y = data.observed[data.weights > 0]
            lower[:, 0] = float(valid_y.min()) - par.target_margin
            upper[:, 0] = float(valid_y.max()) + par.target_margin
        for p, (lo, hi) in par.channel_bounds.get(ch, {}).items():
            k = PARAMETERS.index(p)
            lower[:, k], upper[:, k] = lo, hi
            source[:, k] = f"[parameters.bounds.{ch}] {p}"

        # Where each start value came from: a spec key (checked against the bounds) or "" (a
        # default, the data or a start table: moved onto the nearest bound if outside).
        origin = np.full((n, N_PARAMS), "", dtype=object)
        if start is not None:
            base, beta = np.array(start[0], dtype=np.float64), float(start[1])
        else:
            base = np.array([par.start_of(p) for p in PARAMETERS], dtype=np.float64)[None, :].repeat(n, 0)
            for k, p in enumerate(PARAMETERS):
                if p in par.given:
                    origin[:, k] = f"parameters.start.{p}"
            if "target" not in par.given:
                base[:, 0] = data_targets(data)
            beta = model.beta

        if MEDIAL_PAUSE in phon and start is None:  # a weak medial pause: its neighbours dominate it (coartic.pauses)
            base[phon.index(MEDIAL_PAUSE), PARAMETERS.index("alpha")] = MEDIAL_ALPHA
        for j, o in enumerate(par.overrides):
            for i, p in enumerate(phon):
                if not o.applies(p, ch):
                    continue
                for name, (lo, hi) in o.bounds.items():
                    k = PARAMETERS.index(name)
                    lower[i, k], upper[i, k] = lo, hi
                    source[i, k] = f"[override #{j + 1}] bounds.{name}"
                for name, val in o.start.items():
                    k = PARAMETERS.index(name)
                    base[i, k] = val
                    if start is None:
                        origin[i, k] = f"override #{j + 1}.start.{name}"
                for name in o.free:
                    free[i, PARAMETERS.index(name)] = True
                for name, val in o.fixed.items():
                    k = PARAMETERS.index(name)
                    # named (for errors) but never checked against bounds: a fixed value is not free
                    base[i, k], free[i, k], origin[i, k] = val, False, f"override #{j + 1}.fixed.{name}"

        ref = model.reference_for(phon)
        if ref not in phon:
            raise SpecError.at(where, "model.reference_phoneme", f"{ref!r} does not occur in "
                               f"the {ch} data (phonemes: {' '.join(phon)}); name one that does, or leave "
                               "reference_phoneme out to let the data choose")
        r = phon.index(ref)
        ka = PARAMETERS.index("alpha")
        free[r, ka], base[r, ka] = False, 1.0

        ties: list[tuple[int, int]] = []
        tied_by: dict[tuple[int, int], int] = {}  # (phoneme row, parameter) -> the [[tie]] that holds it

        def follow(i: int, leader: int, k: int) -> None:
            """Row ``i``'s parameter ``k`` takes ``leader``'s value (a [[tie]], the edge pauses, shared)."""
            free[i, k] = False
            base[i, k] = base[leader, k]
            ties.append((i * N_PARAMS + k, leader * N_PARAMS + k))

        for j, t in enumerate(par.ties):
            if t.channels is not None and ch not in t.channels:
                continue
            rows = [phon.index(p) for p in t.phonemes if p in phon]
            for name in t.parameters:
                k = PARAMETERS.index(name)
                members = [i for i in rows if free[i, k]]
                if len(rows) >= 2 and not members:
                    raise SpecError.at(where, f"tie #{j + 1}", f"{name} is free for none of {list(t.phonemes)} "
                                       f"on {ch}: nothing to tie")
                again = [i for i in rows if (i, k) in tied_by]
                if again:
                    i = again[0]
                    raise SpecError.at(where, f"tie #{j + 1}", f"ties {name} of {list(t.phonemes)} on {ch}, but "
                                       f"{phon[i]}.{name} is in [[tie]] #{tied_by[i, k] + 1} already: a parameter is "
                                       f"tied by one [[tie]] only; put the phonemes of both in one tie",
                                       phoneme=phon[i], parameter=name)
                held = [i for i in rows if not free[i, k]]
                if members and held:
                    # a tie means one shared value: a member held at its own value would silently not share it
                    i = held[0]
                    by = f"[{origin[i, k]}]" if origin[i, k] else f"{name} is not in [parameters] free for it"
                    raise SpecError.at(where, f"tie #{j + 1}", f"ties {name} of {list(t.phonemes)} on {ch}, but "
                                       f"{phon[i]}.{name} is fixed ({by}): free it, or take {phon[i]} out of the tie",
                                       phoneme=phon[i])
                if len(members) < 2:
                    continue  # fewer than two present (and free) here: nothing to share
                leader = members[0]
                tied_by.update({(i, k): j for i in members})
                for i in members[1:]:
                    follow(i, leader, k)
        # The edge pauses share one dominance magnitude α (coartic.pauses, EDGE_TIED): their
        # postures are their targets. A separate α per edge bends each edge's transition to fit the
        # training rate's timing and does not carry to another rate (docs/REAL_DATA.md, "Why the
        # synthetic figures moved"); a [[tie]] of α that holds either pause already decides.
        if PAUSE in phon and FINAL_PAUSE in phon:
            for name in EDGE_TIED:
                k = PARAMETERS.index(name)
                lead, final = phon.index(PAUSE), phon.index(FINAL_PAUSE)
                if free[lead, k] and free[final, k] and (lead, k) not in tied_by and (final, k) not in tied_by:
                    follow(final, lead, k)
        for name in par.shared:  # one value per channel: every phoneme where it is free takes the first's
            k = PARAMETERS.index(name)
            members = [i for i in range(n) if free[i, k]]
            for i in members[1:]:
                follow(i, members[0], k)
        priors = expand_priors(settings, ch, tuple(phon), free, par.fit_beta and model.variant == "modified")
        if not isinstance(settings.priors.target_prior, str):  # "estimated": a family of the pool (build_problem)
            priors.update(target_priors(settings.priors.target_prior, data.utterances, ch, phon, free, priors))
        bad = lower > upper
        if bad.any():
            i, k = map(int, np.argwhere(bad)[0])
            raise SpecError.at(where, f"parameters.bounds.{PARAMETERS[k]}", f"bounds of {phon[i]}.{PARAMETERS[k]} on "
                               f"{ch}: low {lower[i, k]} > high {upper[i, k]} (with the overrides)", phon[i],
                               parameter=PARAMETERS[k])
        outside = free & ((base < lower) | (base > upper)) & (origin != "")
        if outside.any():
            i, k = map(int, np.argwhere(outside)[0])
            raise SpecError.at(where, str(origin[i, k]), f"start {base[i, k]:g} of {phon[i]}.{PARAMETERS[k]} on {ch} "
                               f"is outside its bounds [{lower[i, k]:g}, {upper[i, k]:g}]", phoneme=phon[i])
        # A default (or data, or start-table) value outside a box starts on its nearest bound.
        base = np.where(free, np.clip(base, lower, upper), base)
        beta_free = par.fit_beta and model.variant == "modified"
        beta = float(np.clip(beta, *par.beta_bounds)) if beta_free else beta
        ps = cls(ch, tuple(phon), base, free, lower, upper, beta, beta_free, par.beta_bounds, priors=priors,
                 origins=origin)
        ps.ties = tuple(ties)
        ps.bound_sources = {f"{p}.{q}": str(source[i, k])
                            for i, p in enumerate(phon) for k, q in enumerate(PARAMETERS) if free[i, k]}
        if beta_free:
            ps.bound_sources[BETA] = par.bound_source(BETA)
        return ps

    def packing(self) -> Packing:
        """The engines' view: the free entries, their bounds and the transform to x."""
        return Packing(self.phonemes, self.free.copy(), self.beta_free, self.lower.copy(), self.upper.copy(),
                       self.beta_bounds, self.matrix.copy(), self.beta, self.origins, self.ties,
                       dict(self.bound_sources), self.mixes)

    @classmethod
    def from_packing(cls, channel: str, packing: Packing, names: list[str] | None = None,
                     stderr: FloatArray | None = None, at_bound: list[str] | None = None,
                     unidentified: list[str] | None = None, priors: Mapping[str, Prior] | None = None,
                     bound_notes: Mapping[str, BoundNote] | None = None) -> ParameterSet:
        """The set a packing holds (its base values), with a fit's standard errors (and at-bound
        explanations) by free name."""
        se = dict(zip(names, map(float, stderr))) if names is not None and stderr is not None else {}
        ps = cls(channel, tuple(packing.phonemes), packing.base.copy(), packing.free.copy(), packing.lower.copy(),
                 packing.upper.copy(), packing.base_beta, packing.beta_free, packing.beta_bounds, priors=priors,
                 stderr=se,
                 at_bound=frozenset(at_bound or ()), unidentified=frozenset(unidentified or ()),
                 bound_notes=bound_notes)
        ps.ties = tuple(packing.ties)
        ps.mixes = tuple(packing.mixes)
        ps.bound_sources = dict(packing.bound_sources or {})
        return ps

    # ------------------------------------------------------------------ output
    def rows(self) -> list[dict[str, object]]:
        """One row per parameter (β only when free): what ``parameters.csv`` holds."""
        out: list[dict[str, object]] = []
        for name in self:
            p = self[name]
            if p.parameter == BETA and not p.free:
                continue
            bn = p.bound_note if p.at_bound else None  # a tied entry shares its carrier's
            out.append({"channel": self.channel, "phoneme": p.phoneme, "parameter": p.parameter, "value": p.value,
                        "stderr": p.stderr if p.free or p.tied_to else "", "free": p.free, "tied_to": p.tied_to or "",
                        # one value for these phonemes (carrier first): "all" when every phoneme shares it
                        "shared_by": ("all" if set(p.shared_by) >= set(self.phonemes) else " ".join(p.shared_by))
                        if p.shared_by else "",
                        "lower": p.lower, "upper": p.upper,
                        "at_bound": p.at_bound, "unidentified": not p.identified,
                        # why it is at a bound: which side, the category, the computed sentence
                        "bound_side": bn.side if bn else "", "bound_category": bn.category if bn else "",
                        "bound_source": bn.source if bn else "",
                        "bound_explanation": f"{bn.explanation} {bn.reading}" if bn else "",
                        "prior_mean": p.prior.mean if p.prior else "", "prior_sd": p.prior.sd if p.prior else "",
                        "prior_scale": ("log" if p.prior.log else "natural") if p.prior else ""})
        return out


def expand_priors(settings: EstimationSettings, channel: str, phonemes: tuple[str, ...], free: BoolArray,
                  beta_free: bool) -> dict[str, Prior]:
    """``[parameters.prior]`` per free entry of one channel: "theta_bw" applies to every phoneme whose
    θ_bw is free, "p.k_r" to one (a more specific key wins). A prior on nothing free is refused; one
    on a phoneme absent from this channel's data applies to nothing here."""
    out: dict[str, Prior] = {}
    given, where = settings.priors.priors, settings.source
    for key in sorted(given, key=lambda k: "." in k):  # global keys first, specific ones override
        mean, sd, log = given[key]
        phoneme, _, name = key.rpartition(".")
        if name == BETA:
            if not beta_free:
                raise SpecError.at(where, f"parameters.prior.{key}", f"beta is not fitted ([model] fit_beta)")
            out[BETA] = Prior(mean, sd, log)
            continue
        k = PARAMETERS.index(name)
        if phoneme:
            if phoneme not in phonemes:
                continue
            if not free[phonemes.index(phoneme), k]:
                raise SpecError.at(where, f"parameters.prior.{key}", f"{key} is not free on {channel}: a prior on "
                                   "a fixed value would do nothing")
            out[key] = Prior(mean, sd, log)
        else:
            if not free[:, k].any():
                raise SpecError.at(where, f"parameters.prior.{key}", f"{name} is free for no phoneme on {channel}")
            for i, p in enumerate(phonemes):
                if free[i, k]:
                    out[f"{p}.{name}"] = Prior(mean, sd, log)
    return out


def data_targets(data: ChannelData) -> FloatArray:
    """Mean observed value at the segment midpoints of each phoneme (its acoustic centre)."""
    sums = np.zeros(len(data.phonemes))
    counts = np.zeros(len(data.phonemes))
    row = {p: i for i, p in enumerate(data.phonemes)}
    for u, utt in enumerate(data.utterances):
        sl = data.utterance_samples(u)
        y, w = data.observed[sl], data.weights[sl]
        for lab, s, e in zip(utt.labels, utt.starts, utt.ends):
            j = int(np.clip(np.searchsorted(utt.times, 0.5 * (s + e)), 0, len(utt.times) - 1))
            if w[j] > 0:
                sums[row[lab]] += y[j]
                counts[row[lab]] += 1
    fallback = float(np.average(data.observed, weights=data.weights))
    return np.where(counts > 0, sums / np.maximum(counts, 1), fallback)
