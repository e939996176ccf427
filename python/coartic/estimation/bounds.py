"""Why a fitted parameter sits on a bound: a computed explanation for each one (lmfit warns; this says why).

For every free parameter at a bound at the optimum x̂ of a channel's fit, ``explain_bounds``
measures, on the fit's own objective (``ChannelProblem``: residuals, exact Jacobian, batch SSE):

- which bound (lower/upper, its value) and where the box comes from: the model's own domain
  (k_R ∈ [0, 1], β ≥ 0: MODEL.md §1, §3.1) or a box the spec or the defaults set (the spec key, or
  ``DEFAULT_FIT_BOUNDS``; ``Packing.bound_sources``);
- the pull of the data: g = d(SSE)/d(value) at the bound, and what relaxing the bound would gain,
  measured by evaluating the model past the bound: (a) that parameter alone moved 1 %…100 % of
  its box width beyond the bound, the others held; (b) along the Gauss–Newton direction in which
  the other free parameters not at a bound re-adjust (d = −g_i (H_AA)⁺ e_i, H = 2JᵀJ), which
  catches a parameter whose pull is taken up by a correlated one;
- how much the data constrain it inside the box: the SSE over its whole box, others held.

Gains are in units of the residual variance s² = SSE/(n − m) (Δχ²; one unit is the
likelihood-ratio scale of one parameter for independent noise; the samples of a trajectory are
correlated, so Δχ² overstates the evidence, which errs towards calling a bound active).

The category is one of a closed set (``CATEGORIES``):

``domain``       the bound is a limit of the model itself: by design (MODEL.md says what it means);
``active``       the data pull beyond a box the spec or the defaults set: relaxing it gains Δχ² ≥ 1;
``optimal``      relaxing it gains Δχ² < 1 although the data constrain it (moving it past the
                 bound, or across its box, costs Δχ² ≥ 1): a wider box would not change the fit. Either
                 its best value is the bound itself, within the noise, or past the bound the SSE is
                 flat (a saturated direction: any value beyond fits as well) while the box's inside
                 costs;
``insensitive``  relaxing it gains Δχ² < 1 and moving it past the bound and across its whole box
                 costs Δχ² < 1 too: the data do not constrain it (any value fits as well);
``unexplained``  the diagnostic cannot account for it: the objective falls back into the box
                 (the engine stopped on the bound without being held there). A finding, never hidden.

Each note carries a sentence with the numbers and a model/phonetic reading by parameter family in
MODEL.md's terms (dominance, resistance, shape, target).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np
from numpy.typing import NDArray

# BoundNote, the record this module computes, lives with the parameter it explains
from coartic.estimation.parameters import CATEGORIES, BoundNote, psd_pseudo_inverse
from coartic.estimation.packing import shared_words, tie_group
from coartic.settings import default

if TYPE_CHECKING:
    from coartic.estimation.problem import ChannelProblem

FloatArray = NDArray[np.float64]

# Δχ² (SSE in units of s²) below which a change is within the noise.
CHI2_NOISE = 1.0
# Limits of the model itself (MODEL.md §1 table and §3.1: the extents weigh the next one by 1 − k_R;
# β ≥ 0 in ρ). α, θ, ψ > 0 are open limits a log-scale fit never reaches.
DOMAIN: dict[str, tuple[float, float]] = {"k_r": (0.0, 1.0), "beta": (0.0, math.inf)}
# Phonemes whose resistance MODEL.md names: bilabial closure and labiodental contact.
CONTACT_PHONEMES = frozenset({"p", "b", "m", "f", "v"})
LIP_CHANNELS = frozenset({"ULO", "LLO", "ULP", "LLP", "LR", "LA"})
# Probe steps past the bound, as fractions of the box width (internal units: log for θ, α, ψ, β).
STEPS_OUT = (0.01, 0.03, 0.1, 0.3, 1.0)
STEPS_IN = (0.01, 0.03, 0.1, 0.25, 0.5, 0.75, 1.0)
GN_SCALES = (0.05, 0.1, 0.25, 0.5, 1.0)


def explain_bounds(problem: ChannelProblem, x: FloatArray, at_bound: Sequence[str], jac: Any, r: FloatArray,
                   s2: float, corr: FloatArray | None = None) -> dict[str, BoundNote]:
    """A note per name in ``at_bound`` (free names at a bound at ``x``), from the problem itself.

    ``jac`` and ``r`` are the problem's Jacobian and residuals at ``x`` (parameter_stats has them);
    ``s2`` the residual variance; ``corr`` the parameters' correlation matrix (names' order).
    Costs a few batched SSE evaluations per parameter at a bound.
    """
    if not at_bound:
        return {}
    pk = problem.packing
    names = pk.names()
    lo, hi = pk.bounds()
    x = np.asarray(x, dtype=np.float64)
    m = len(names)
    n = max(problem.data.n_valid, 1)
    sse = float(r @ r)
    n_data = problem.data.corpus.n_samples
    rmse = float(np.sqrt(float(r[:n_data] @ r[:n_data]) / n))
    s2 = max(float(s2), 1e-300)
    g = 2.0 * np.asarray(jac.T @ r).ravel()
    jtj = np.asarray((jac.T @ jac).toarray()) if hasattr(jac, "toarray") else np.asarray(jac.T @ jac)
    h = 2.0 * jtj
    dv = pk.dvalue_dx(x)
    nat = pk.natural(x)
    params, beta = pk.unpack(x)
    fitted: FloatArray | None = None  # the model at x, for the k_R notes (one evaluation, when needed)
    idx = [names.index(nm) for nm in at_bound]
    interior = np.array([j for j in range(m) if j not in set(idx)], dtype=np.int64)
    h_ff_pinv = psd_pseudo_inverse(h[np.ix_(interior, interior)])[0] if interior.size else np.zeros((0, 0))

    # every probe of every parameter in one batch (the core's parallel path)
    rows: list[FloatArray] = [x.copy()]
    plan: list[dict[str, Any]] = []
    for i in idx:
        side = "upper" if abs(x[i] - hi[i]) <= abs(x[i] - lo[i]) else "lower"
        out = 1.0 if side == "upper" else -1.0
        xb = hi[i] if side == "upper" else lo[i]
        width = float(hi[i] - lo[i]) if np.isfinite(hi[i] - lo[i]) else 1.0
        p: dict[str, Any] = {"i": i, "side": side, "out": out, "xb": xb, "width": width}
        # the others re-adjusted: the Gauss–Newton step of the quadratic model, the bound relaxed
        hi_col = h[interior, i]
        schur = float(h[i, i] - hi_col @ h_ff_pinv @ hi_col) if interior.size else float(h[i, i])
        p["gn_gain"] = g[i] ** 2 / (2.0 * schur) if schur > 1e-12 * max(h[i, i], 1e-300) else math.inf
        d = np.zeros(m)
        if math.isfinite(p["gn_gain"]) and schur > 0:
            d[i] = -g[i] / schur
            if interior.size:
                d[interior] = -(h_ff_pinv @ hi_col) * d[i]
        p["rows_out"] = _add(rows, x, i, [xb + out * s * width for s in STEPS_OUT])
        p["rows_in"] = _add(rows, x, i, [xb - out * s * width for s in STEPS_IN])
        # a step larger than a box (a nearly flat direction) says nothing a shorter one does not: cap it
        widths = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
        d *= min(1.0, 1.0 / max(float(np.max(np.abs(d) / widths)), 1e-300))
        gn_rows = []
        if d[i] * out > 0:  # the step goes past the bound (it does when the data pull outward)
            for s in GN_SCALES:
                y = x + s * d
                y[interior] = np.clip(y[interior], lo[interior], hi[interior])
                gn_rows.append(len(rows))
                rows.append(y)
        p["rows_gn"] = gn_rows
        plan.append(p)
    with np.errstate(over="ignore", invalid="ignore"):  # a probe the model refuses is +inf: not a gain
        ss = np.asarray(problem.sse_batch(np.array(rows)), dtype=np.float64)
    ss = np.where(np.isfinite(ss), ss, np.inf)
    base = float(ss[0]) if np.isfinite(ss[0]) else sse

    notes: dict[str, BoundNote] = {}
    for p in plan:
        i, side, out = p["i"], p["side"], p["out"]
        name = names[i]
        phoneme, parameter = _split(name)
        value = float(nat[i])
        xb = p["xb"]
        bound = float(np.exp(xb)) if pk.log_mask[i] else float(xb)
        dlo, dhi = DOMAIN.get(parameter, (-math.inf, math.inf))
        domain = (side == "lower" and bound == dlo) or (side == "upper" and bound == dhi)
        source = (f"the model's domain ({_DOMAIN_TEXT[parameter]})" if domain
                  else (pk.bound_sources or {}).get(name, "the fit's box"))
        grad = float(g[i])
        grad_of = f"ln {parameter}" if pk.log_mask[i] else parameter
        outward = g[i] * out < 0
        held = (base - ss[p["rows_out"]]) / s2
        j_best = int(np.argmax(held)) if held.size else -1
        gain_held = float(held[j_best]) if held.size and np.isfinite(held[j_best]) else math.nan
        held_x = float(xb + out * STEPS_OUT[j_best] * p["width"]) if j_best >= 0 else math.nan
        held_value = float(np.exp(held_x)) if pk.log_mask[i] and math.isfinite(held_x) else held_x
        inside = (base - ss[p["rows_in"]]) / s2
        k_in = int(np.argmax(inside))
        gain_in = float(inside[k_in])
        in_x = xb - out * STEPS_IN[k_in] * p["width"]
        in_value = float(np.exp(in_x)) if pk.log_mask[i] else float(in_x)
        finite_in = inside[np.isfinite(inside)]
        range_chi2 = float(-finite_in.min()) if finite_in.size else math.nan
        gn_pred = float(p["gn_gain"] / s2) if outward else 0.0
        gn_meas = float(np.max((base - ss[p["rows_gn"]]) / s2)) if p["rows_gn"] else math.nan
        measured = [v for v in (gain_held, gn_meas) if math.isfinite(v)]
        best = max(measured) if measured else math.nan
        rmse_relaxed = float(np.sqrt(max(rmse**2 - max(best, 0.0) * s2 / n, 0.0))) if math.isfinite(best) else rmse
        partner, pc = "", math.nan
        if corr is not None and corr.shape == (m, m):
            c = np.nan_to_num(np.asarray(corr[i], dtype=np.float64).copy())
            c[i] = 0.0
            if c.size and np.max(np.abs(c)) > 0.5:
                jp = int(np.argmax(np.abs(c)))
                partner, pc = names[jp], float(c[jp])

        # the largest SSE rise anywhere it was moved, alone (past the bound and across the box)
        cost = max([-v for v in list(held) + list(inside) if math.isfinite(v)], default=math.nan)
        beyond = max([-v for v in held if math.isfinite(v)], default=math.nan)
        if gain_in >= CHI2_NOISE:
            category = "unexplained"
        elif domain:
            category = "domain"
        elif outward and math.isfinite(best) and best >= CHI2_NOISE:
            category = "active"
        elif outward and not measured and gn_pred >= CHI2_NOISE:
            category = "active"  # past the bound the model cannot be evaluated: the estimate stands
        elif math.isfinite(cost) and cost >= CHI2_NOISE:
            category = "optimal"
        else:
            category = "insensitive"

        sentence = _sentence(category, grad_of, side, grad, outward, gain_held, held_value, gn_pred,
                             gn_meas, range_chi2, cost, beyond, rmse, rmse_relaxed, gain_in, in_value, partner, pc, s2,
                             lo_hi=(_nat(pk, i, lo[i]), _nat(pk, i, hi[i])))
        row = _row(params, pk.phonemes, phoneme)
        group = tie_group(pk.phonemes, pk.ties, phoneme, parameter)
        extra = ""
        if parameter == "k_r" and phoneme in pk.phonemes:
            if fitted is None:
                fitted = np.asarray(problem.evaluate(params, beta), dtype=np.float64)
            gap, count = target_gap(problem, fitted, row, phoneme)
            if count:
                extra = (f" At its {count} target times the fitted {problem.data.channel} is on average "
                         f"{gap:.3g} mm from T·(1 + σ) = {row['target'] * (1 + row['sigma']):.4g} mm.")
        notes[name] = BoundNote(name, phoneme, parameter, value, side, bound, source, category, grad, grad_of,
                                gain_held,
                                held_value, gn_pred, gn_meas, range_chi2, beyond, rmse, rmse_relaxed, partner, pc,
                                sentence, reading(parameter, side, value, phoneme, problem, bound, row, group) + extra,
                                group)
    return notes


def summary_counts(notes: dict[str, BoundNote]) -> str:
    """'8 model domain, 5 active' (categories in CATEGORIES order)."""
    counts = {c: sum(nt.category == c for nt in notes.values()) for c in CATEGORIES}
    words = {"domain": "model domain", "active": "active", "optimal": "not binding", "insensitive": "insensitive",
             "unexplained": "UNEXPLAINED"}
    return ", ".join(f"{k} {words[c]}" for c, k in counts.items() if k)


# --------------------------------------------------------------------------------------------------
_DOMAIN_TEXT = {"k_r": "k_R ∈ [0, 1], MODEL.md §1 and §3.1", "beta": "β ≥ 0, MODEL.md §3.1"}


def _add(rows: list[FloatArray], x: FloatArray, i: int, values: list[float]) -> list[int]:
    out = []
    for v in values:
        y = x.copy()
        y[i] = v
        out.append(len(rows))
        rows.append(y)
    return out


def _nat(pk: Any, i: int, xv: float) -> float:
    return float(np.exp(xv)) if pk.log_mask[i] else float(xv)


def _split(name: str) -> tuple[str, str]:
    if name == "beta":
        return "*", "beta"
    phoneme, _, parameter = name.rpartition(".")
    return phoneme, parameter


def _chi(v: float) -> str:
    v += 0.0  # no "-0"
    return "n/a" if not math.isfinite(v) else (f"{v:.3g}" if abs(v) < 1e4 else f"{v:.2e}")


def _sentence(category: str, grad_of: str, side: str, grad: float, outward: bool, gain_held: float,
              held_value: float, gn_pred: float, gn_meas: float, range_chi2: float, cost: float, beyond_chi2: float,
              rmse: float,
              rmse_relaxed: float, gain_in: float, in_value: float, partner: str, pc: float, s2: float,
              lo_hi: tuple[float, float]) -> str:
    beyond = "above" if side == "upper" else "below"
    pull = (f"d(SSE)/d({grad_of}) = {grad:+.3g} mm² at the bound: the data pull {beyond} it" if outward
            else f"d(SSE)/d({grad_of}) = {grad:+.3g} mm² at the bound: no pull {beyond} it")
    if math.isfinite(gain_held):
        held = (f"moved alone past the bound, the SSE at best {'falls' if gain_held > 0 else 'rises'} by "
                f"{abs(gain_held) * s2:.3g} mm² (Δχ² {-gain_held + 0.0:+.3g}, at {held_value:.4g})")
    else:
        held = "past the bound the model is not defined, so it was not moved there"
    gn = f"with the other free parameters re-adjusted, Gauss–Newton predicts a gain of Δχ² {_chi(gn_pred)}"
    if math.isfinite(gn_meas):
        gn += f" and the model measured along that step gives Δχ² {_chi(gn_meas)}"
    corr = f"; it trades off with {partner} (r = {pc:+.2f})" if partner else ""
    s2_txt = f"Δχ² = ΔSSE/s², s² = {s2:.3g} mm²"
    if category == "unexplained":
        return (f"at {in_value:.4g}, inside the box, the SSE is lower by Δχ² {_chi(gain_in)}: neither the data nor the "
                f"model hold it at the bound (not converged in this coordinate, or another minimum); {pull}{corr} "
                f"({s2_txt}).")
    if category == "domain":
        want = (f"the data would take it {beyond} the model's range (Gauss–Newton gain, were that allowed: "
                f"Δχ² {_chi(gn_pred)})" if outward else "the data do not pull it out of the model's range")
        return f"{pull}; {want}{corr} ({s2_txt})."
    if category == "active":
        return (f"{pull}; {held}; {gn}. Relaxing the bound would lower the RMSE by about "
                f"{rmse - rmse_relaxed:.2g} mm ({rmse:.5f} → {rmse_relaxed:.5f} mm){corr} ({s2_txt}).")
    gains = f"relaxing the bound gains less than the noise (Δχ² < {CHI2_NOISE:g})"
    if category == "optimal":
        if math.isfinite(beyond_chi2) and beyond_chi2 < CHI2_NOISE:
            return (f"{pull}; {held}; {gn}: {gains}. Past the bound the SSE changes by at most Δχ² {_chi(beyond_chi2)} "
                    f"(any value beyond fits as well: the bound caps a direction the data cannot tell apart), while "
                    f"moving it into the box costs up to Δχ² {_chi(range_chi2)}: a wider box would not change the fit"
                    f"{corr} ({s2_txt}).")
        return (f"{pull}; {held}; {gn}: {gains}, while moving it costs up to Δχ² {_chi(cost)}: its best value is "
                f"the bound itself, within the noise{corr} ({s2_txt}).")
    return (f"{pull}; {held}; {gn}: {gains}, and over its whole box [{lo_hi[0]:.4g}, {lo_hi[1]:.4g}] and past it "
            f"the SSE changes by at most Δχ² {_chi(cost)}: the data do not constrain it, any value fits as well"
            f"{corr} ({s2_txt}).")


def _row(params: FloatArray, phonemes: Sequence[str], phoneme: str) -> dict[str, float]:
    from coartic.table import PARAMETERS

    if phoneme not in phonemes:
        return {}
    return dict(zip(PARAMETERS, map(float, params[list(phonemes).index(phoneme)])))


def target_gap(problem: ChannelProblem, fitted: FloatArray, row: dict[str, float], phoneme: str) -> tuple[float, int]:
    """Mean |F(t_i) − T·(1 + σ)| over the phoneme's segments (t_i its target time, MODEL.md §1, at the
    nearest valid sample) and their number: whether the fit reaches the phoneme's target."""
    d = problem.data
    a = float(problem.options.apex_fraction)
    goal = row.get("target", math.nan) * (1.0 + row.get("sigma", 0.0))
    gaps: list[float] = []
    for u, utt in enumerate(d.utterances):
        sl = d.utterance_samples(u)
        for lab, s0, e0 in zip(utt.labels, utt.starts, utt.ends):
            if lab != phoneme:
                continue
            t = min(max(s0 + a * (e0 - s0) + row.get("delta", 0.0), s0), e0)
            j = int(np.clip(np.searchsorted(utt.times, t), 0, len(utt.times) - 1))
            if j > 0 and abs(utt.times[j - 1] - t) < abs(utt.times[j] - t):
                j -= 1
            if d.weights[sl][j] > 0:
                gaps.append(abs(float(fitted[sl][j]) - goal))
    return (float(np.mean(gaps)) if gaps else math.nan), len(gaps)


def _reach_ms(theta: float, c: float) -> float:
    """θ^(−1/c) in ms: where θ r^c = 1, i.e. D has fallen to α/e (r measured from the plateau's edge)."""
    return 1e3 * theta ** (-1.0 / c) if theta > 0 and c > 0 else math.nan


def reading(parameter: str, side: str, value: float, phoneme: str, problem: ChannelProblem, bound: float,
            row: dict[str, float] | None = None, shared_by: Sequence[str] = ()) -> str:
    """What this bound means for the model, in MODEL.md's terms (dominance D, resistance R, shape S);
    ``row`` is the phoneme's fitted parameters (for θ, the reach θ^(−1/c) uses its c); ``shared_by``
    the phonemes that share the value (a shared θ_bw is every phoneme's reach, not its carrier's)."""
    row = row or {}
    opts = problem.options
    plateau = getattr(opts, "dominance", default("dominance")) == "plateau"
    handover = bool(getattr(opts, "handover", False))
    ch = problem.data.channel
    up = side == "upper"
    ph = shared_words(shared_by, problem.packing.phonemes, parameter) if shared_by else f"/{phoneme}/"
    if parameter == "k_r":
        if up:
            where = ("the contact the Cosi–Perin resistance exists for (bilabial closure /p b m/, labiodental /f v/)"
                     if phoneme in CONTACT_PHONEMES and ch in LIP_CHANNELS else
                     f"here the data say {ph} reaches its target on {ch}, as MODEL.md reserves for /p b m f v/ contact")
            return (f"k_R = {value:.3g}: full resistance — the neighbours' R ends at {ph}'s target time, so {ph} "
                    f"reaches its target exactly (F(t_i) = T·S(0)) at any rate (MODEL.md §3 item 3): {where}.")
        contact = (f" MODEL.md reserves k_R = 1 for the contact of /p b m f v/; on {ch} the data give {ph} none."
                   if phoneme in CONTACT_PHONEMES and ch in LIP_CHANNELS else "")
        return (f"k_R = {value:.3g}: no resistance — {ph} does not cut its neighbours' dominance short; their R "
                f"extents run on through it (MODEL.md §3.1), so around {ph} the model is the original eq. 1.{contact}")
    if parameter == "beta":
        return (f"β = {value:.3g}: R = exp(−βu/(1 − u)) falls " + ("as steeply as allowed after each target."
                if up else "as slowly as allowed: R is nearly flat until its extent."))
    if parameter == "target":
        return (f"T = {value:.4g} mm at the {'top' if up else 'bottom'} of its box: {ph} heads for a value beyond "
                f"anything measured on {ch} — its target is never reached (undershoot) or trades off with α, σ.")
    if parameter == "alpha":
        return (f"α = {value:.3g} (relative to the reference phoneme's α = 1): " +
                (f"{ph}'s dominance swamps its neighbours' in its segment as much as allowed." if up else
                 f"{ph} hardly dominates: its neighbours' targets set {ch} during its segment (transparent)."))
    if parameter in ("theta_bw", "theta_fw"):
        bw = parameter == "theta_bw"
        c = row.get("c_bw" if bw else "c_fw", 1.0)
        reach = _reach_ms(value, c)
        # θ is in s^-c: the same box allows very different reaches at different c
        unit = (f" (θ is in s^-c: the box's {bound:g} allows reaches down to {_reach_ms(bound, 1.0):.3g} ms at c = 1 "
                f"but only {_reach_ms(bound, 3.0):.3g} ms at c = 3)") if up else ""
        edge = " beyond its plateau's edge" if plateau else " from its target time"
        span = f"reach θ^(−1/c) = {reach:.3g} ms{edge} with {'c_bw' if bw else 'c_fw'} = {c:.3g}{unit}"
        if up:
            if bw and plateau:
                h = float(opts.plateau_fraction)
                return (f"θ_bw = {value:.4g} s^-c, {span}: {ph}'s dominance switches on about as fast as allowed "
                        f"where its plateau begins ({h:g} of its segment's duration before its target time): "
                        "little anticipation before that, as at a gesture's onset.")
            if bw:
                return (f"θ_bw = {value:.4g} s^-c, {span}: the backward (anticipatory) dominance of {ph} decays as "
                        f"fast as allowed: {ph} acts only around and after its own target.")
            if handover:
                return (f"θ_fw = {value:.4g} s^-c, {span}: with handover θ_fw sets how fast {ph} takes over from "
                        f"the segment before it, and {ph} takes over as fast as allowed.")
            return (f"θ_fw = {value:.4g} s^-c, {span}: the carry-over dominance of {ph} ends as fast as allowed "
                    "after its target: little carry-over into the next segment.")
        side_word = "anticipatory" if bw else ("take-over" if handover else "carry-over")
        return (f"{'θ_bw' if bw else 'θ_fw'} = {value:.4g} s^-c, {span}: the {side_word} reach of {ph} is as long "
                "as the box allows: its dominance spreads over its whole neighbourhood.")
    if parameter in ("c_bw", "c_fw"):
        fw = parameter == "c_fw"
        what = (f"the takeover by {ph} from the previous segment (handover)" if fw and handover
                else f"{ph}'s {'forward' if fw else 'backward'} dominance exp(−θ r^c)")
        if up:
            return (f"{parameter} = {value:.3g}: {what} is as flat near its start and as steep further out as "
                    f"c ≤ {bound:g} allows — the data want a flatter onset than this family can make.")
        return (f"{parameter} = {value:.3g}: {what} is as cusp-like as allowed: sharp at its peak, long tails.")
    if parameter == "sigma":
        return (f"σ = {value:+.3g}: S = 1 + σ exp(−ψτ²) " +
                (f"magnifies {ph}'s target near its time as much as allowed (T(1 + σ)): an overshoot such as "
                 "lip compression in a bilabial closure or the opening of /a/." if up else
                 f"shrinks {ph}'s target near its time as much as allowed (T(1 + σ)): the channel turns back "
                 "before the target."))
    if parameter == "psi":
        half = f"{1e3 / math.sqrt(value):.3g} ms" if value > 0 else "n/a"
        return (f"ψ = {value:.4g} s^-2: the shape S of {ph} is as " + ("brief" if up else "long") +
                f" as allowed (half-width 1/√ψ ≈ {half}).")
    if parameter == "delta":
        return (f"δ = {value * 1e3:+.3g} ms: {ph}'s target time is as {'late' if up else 'early'} as allowed "
                "relative to its segment's apex (it is clamped into its own segment anyway).")
    return f"{parameter} = {value:.4g} at its {side} bound."
