"""The model from Python: segment lists and a parameter table in, channel trajectories out.

This is what the animation runtime, the corpus generator and the fitting code call. The heavy
lifting is in the Rust core (``coartic._core``); this module turns labels into phoneme rows,
checks segment lists with messages that name the utterance and label at fault (utterances and
segments counted from 1, as everywhere in coartic), turns the core's ``_core.CoarticError`` into
a ``ModelInputError`` naming the channel and phoneme. It imports no SciPy, so that the runtime
(``animate``, ``speak``) starts without it: the Jacobian as a ``scipy.sparse`` matrix, which fitting
uses, is in ``coartic.jacobian``.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from coartic import _core
from coartic.errors import CoarticError
from coartic.io.errors import DataError
from coartic.io.labelmap import LabelMap, resolve_label_map
from coartic.pauses import FINAL_PAUSE, MEDIAL_PAUSE, SHORT_PAUSE_S, pause_postures, recorded, recorded_short
from coartic.table import N_PARAMS, PARAMETERS, PAUSE, ChannelSettings, ParameterTable

F64 = npt.NDArray[np.float64]


class ModelInputError(CoarticError, ValueError):
    """Invalid segments, times, labels or parameters given to the model; the message names the
    utterance and label (or channel, phoneme and parameter).

    Attributes as ``coartic.errors.CoarticError`` (indices from 0; ``phoneme`` is the phoneme's
    name), plus ``channel``; ``None`` where they do not apply.
    """

    channel: str | None = None

    def __init__(
        self,
        message: str,
        *,
        channel: str | None = None,
        utterance: int | None = None,
        segment: int | None = None,
        phoneme: str | None = None,
        parameter: str | None = None,
        value: float | None = None,
        sample: int | None = None,
        reason: str | None = None,
    ) -> None:
        super().__init__(message)
        self.channel, self.utterance, self.segment = channel, utterance, segment
        self.phoneme, self.parameter, self.value = phoneme, parameter, value
        self.sample, self.reason = sample, reason


def _vector(x: npt.ArrayLike, what: str, where: str) -> F64:
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise ModelInputError(f"{where}: {what} must be numbers, got {x!r:.80}") from None
    if a.ndim != 1:
        raise ModelInputError(f"{where}: {what} must be one-dimensional, got shape {a.shape}")
    bad = np.flatnonzero(~np.isfinite(a))
    if bad.size:
        raise ModelInputError(f"{where}: {what}[{bad[0]}] = {a[bad[0]]} is not finite")
    return a


BoolArray = npt.NDArray[np.bool_]


class Utterance:
    """One utterance: the single description every part uses (model, fit, MCMC, score).

    Segment labels (model phonemes, pauses ``"#"``), their start and end times (s), and the times
    (s) at which to evaluate the channels; ``name`` appears in error messages. A recorded utterance
    also carries its observed channels (``observed``: channel -> values, NaN where not measured),
    which samples are usable (``valid``: channel -> bool mask; weight 0 elsewhere) and metadata
    from its manifest row (``meta``: stimulus, vowel, consonant, repetition, rate, speaker, ...).

    Times are checked (numbers, one-dimensional, finite) here, so the error names the utterance;
    labels against a phoneme list and segment order are checked by ``build_corpus``.
    """

    __slots__ = ("labels", "starts", "ends", "times", "name", "observed", "valid", "meta")

    def __init__(self, labels: Sequence[str], starts: npt.ArrayLike, ends: npt.ArrayLike, times: npt.ArrayLike,
                 name: str = "", observed: dict[str, F64] | None = None, valid: dict[str, BoolArray] | None = None,
                 meta: dict[str, str] | None = None) -> None:
        where = f"utterance {name!r}" if name else "utterance"
        self.name = name
        self.labels: tuple[str, ...] = tuple(labels)
        self.starts: F64 = _vector(starts, "starts", where)
        self.ends: F64 = _vector(ends, "ends", where)
        self.times: F64 = _vector(times, "times", where)
        self.observed: dict[str, F64] = {} if observed is None else observed
        self.valid: dict[str, BoolArray] = {} if valid is None else valid
        self.meta: dict[str, str] = {} if meta is None else meta

    def __repr__(self) -> str:
        return (f"Utterance({self.name!r}, {len(self.labels)} segments, {self.times.size} samples, "
                f"channels {sorted(self.observed)})")

    def sample_segments(self) -> npt.NDArray[np.int64]:
        """For each sample, the index of the segment it lies in (−1 outside every segment)."""
        i = np.searchsorted(self.starts, self.times, side="right") - 1
        inside = (i >= 0) & (self.times < self.ends[np.clip(i, 0, None)])
        return np.where(inside, i, -1).astype(np.int64)


def utterances_for_table(table: ParameterTable, utterances: Sequence[Utterance]) -> list[Utterance]:
    """The utterances (labels already the table's phonemes) as ``table`` reads them: with the pause
    postures it was fitted with (``coartic.pauses.recorded``; samples, channels and meta kept), as
    they are for a table that records none."""
    if not recorded(table.metadata):
        return list(utterances)
    short, have = recorded_short(table.metadata), set(table.phonemes)
    out = []
    for u in utterances:
        labs, s, e, _ = pause_postures(u.labels, u.starts, u.ends, short, have)
        out.append(u if labs == u.labels and s.size == u.starts.size else
                   Utterance(labs, s, e, u.times, u.name, u.observed, u.valid, u.meta))
    return out


def utterances_with_postures(utterances: Sequence[Utterance], short: float = SHORT_PAUSE_S
                             ) -> tuple[list[Utterance], list[str]]:
    """``coartic.pauses.pause_postures`` on every utterance (samples, channels and meta kept), and a note naming
    each change but the final pauses' (one per utterance, counted in one note)."""
    out: list[Utterance] = []
    notes: list[str] = []
    finals = 0
    done = [(u, *pause_postures(u.labels, u.starts, u.ends, short)) for u in utterances]
    # A posture no sample shows is not fitted: a row whose segments hold no valid sample in any
    # channel is determined only through its reach into the neighbours, its target unidentified
    # (the German EMA's final pauses lie where the recordings are NaN: their '#end' target went to
    # the bottom of its box, flagged "not identified", and the unpooled per-phoneme fit became
    # start-dependent, 0.82 mm held out, docs/REAL_DATA.md). Those pauses stay '#', and a table
    # without the row reads them as '#' too (STAND_INS).
    unseen = [p for p in (FINAL_PAUSE, MEDIAL_PAUSE)
              if any(p in labels for _, labels, _, _, _ in done)
              and not any(lab == p and _observed(u, s, e) for u, labels, starts, ends, _ in done
                          for lab, s, e in zip(labels, starts, ends))]
    for u, labels, starts, ends, changes in done:
        if unseen:
            labels = tuple(PAUSE if lab in unseen else lab for lab in labels)
            changes = [c for c in changes if c.became not in unseen]
        if not changes and labels == u.labels and starts.size == u.starts.size:
            out.append(u)
            continue
        out.append(Utterance(labels, starts, ends, u.times, u.name, u.observed, u.valid, u.meta))
        finals += sum(c.became == FINAL_PAUSE for c in changes)
        where = u.meta.get("file") or u.name
        notes += [f"pauses: {where}: {c.text()}" for c in changes if c.became != FINAL_PAUSE]
    notes += [f"pauses: no {'utterance-final' if p == FINAL_PAUSE else 'medial'} pause has a valid sample in any "
              f"channel: none is fitted as {p!r} (a posture no sample shows cannot be estimated); they stay "
              f"{PAUSE!r}" for p in unseen]
    if finals:
        notes.insert(0, f"pauses: {finals} utterance-final pause(s) fitted as {FINAL_PAUSE!r} (their own target and θ), "
                        f"apart from the initial {PAUSE!r}; where α is free the two share one "
                        f"(coartic.pauses.EDGE_TIED)")
    return out, notes


def _observed(u: Utterance, start: float, end: float) -> bool:
    """Whether any channel of ``u`` has a valid, finite sample in [start, end) (an utterance that
    carries no channels counts as observed: nothing to tell)."""
    if not u.valid:
        return True
    inside = (u.times >= start) & (u.times < end)
    return any(bool(np.any(v[inside] & np.isfinite(u.observed[ch][inside]))) if ch in u.observed
               else bool(np.any(v[inside])) for ch, v in u.valid.items())


def build_corpus(utterances: Sequence[Utterance], phonemes: Sequence[str]) -> _core.Corpus:
    """Validate utterances and pack them into a ``_core.Corpus``.

    Parameters
    ----------
    utterances : sequence of Utterance
        Labels must be in ``phonemes``; segments sorted, non-overlapping, each with end > start.
    phonemes : sequence of str
        Row order of the parameter matrix: segment label ``phonemes[k]`` uses row k.

    Returns
    -------
    _core.Corpus
        Samples are concatenated in utterance order (utterance u owns
        ``sample_offsets[u]:sample_offsets[u+1]``, i.e. its ``times`` in the given order).

    Raises
    ------
    ModelInputError
        Naming the utterance (by ``name``, else counted from 1) and the segment (counted from 1)
        and label at fault; the indices (from 0) as attributes.
    """
    row_of = {p: i for i, p in enumerate(phonemes)}
    if len(row_of) != len(phonemes):
        dup = next(p for p in phonemes if list(phonemes).count(p) > 1)
        raise ModelInputError(f"phoneme {dup!r} appears twice in the phoneme list")
    seg_offsets = [0]
    sample_offsets = [0]
    rows: list[int] = []
    starts: list[F64] = []
    ends: list[F64] = []
    times: list[F64] = []
    for u, utt in enumerate(utterances):
        where = f"utterance {utt.name!r}" if utt.name else f"utterance {u + 1}"
        labels = list(utt.labels)
        s, e, t = utt.starts, utt.ends, utt.times
        if not (len(labels) == len(s) == len(e)):
            raise ModelInputError(
                f"{where}: {len(labels)} labels, {len(s)} starts and {len(e)} ends: one of each per segment"
            )
        if not labels:
            raise ModelInputError(f"{where}: no segments", utterance=u, reason="no segments")
        for i, lab in enumerate(labels):
            if lab not in row_of:
                known = " ".join(phonemes)
                raise ModelInputError(
                    f"{where}: label {lab!r} (segment {i + 1}) is not a phoneme of the table (known: {known})",
                    utterance=u, segment=i, reason="not a phoneme of the table",
                )
            if not e[i] > s[i]:
                raise ModelInputError(
                    f"{where}: segment {i + 1} {lab!r} ends at {e[i]} s, not after its start {s[i]} s",
                    utterance=u, segment=i, phoneme=lab, value=float(e[i]), reason="end is not after start",
                )
            if i and s[i] < e[i - 1]:
                raise ModelInputError(
                    f"{where}: segment {i + 1} {lab!r} starts at {s[i]} s, before segment {i} "
                    f"{labels[i - 1]!r} ends at {e[i - 1]} s (segments must be sorted and must not overlap)",
                    utterance=u, segment=i, phoneme=lab, value=float(s[i]),
                    reason="starts before the previous segment ends",
                )
        rows.extend(row_of[lab] for lab in labels)
        starts.append(s)
        ends.append(e)
        times.append(t)
        seg_offsets.append(seg_offsets[-1] + len(labels))
        sample_offsets.append(sample_offsets[-1] + len(t))

    def cat(parts: list[F64]) -> F64:
        return np.concatenate(parts) if parts else np.empty(0)

    return _core.Corpus(
        np.asarray(seg_offsets, dtype=np.int64),
        np.asarray(rows, dtype=np.int64),
        cat(starts),
        cat(ends),
        np.asarray(sample_offsets, dtype=np.int64),
        cat(times),
        len(phonemes),
    )


def channel_options(variant: str, settings: ChannelSettings) -> _core.ModelOptions:
    """The core's options of one channel: the variant and the channel's settings (apex fraction,
    edge extent). The one place they are made: a fit makes them from the settings it will write
    into its table, and everything that uses a table (MCMC, score, animation) from the table's."""
    return _core.ModelOptions(variant, settings.apex_fraction, settings.edge_extent, dominance=settings.dominance,
                              plateau_fraction=settings.plateau_fraction, handover=settings.handover)


def model_options(table: ParameterTable, channel: str) -> _core.ModelOptions:
    """The core's options (variant, apex fraction, edge extent) of one channel of the table."""
    table._check_channel(channel)
    return channel_options(table.variant, table.channels[channel])


def jacobian_columns(phonemes: Sequence[str]) -> list[str]:
    """Names of the Jacobian columns: ``"<phoneme>.<parameter>"`` for every row, then ``"beta"``."""
    return [f"{p}.{name}" for p in phonemes for name in PARAMETERS] + ["beta"]


def core_error(err: ValueError, channel: str, phonemes: Sequence[str]) -> ModelInputError:
    """The core's error as a ModelInputError naming the channel and, by name, the phoneme.

    The core names a phoneme by its row of the parameter matrix; ``phonemes`` gives the names in
    row order. The place comes from the error's attributes (``_core.CoarticError``), not from its
    message; any other ValueError is only prefixed with the channel.
    """
    if not isinstance(err, _core.CoarticError):
        return ModelInputError(f"channel {channel!r}: {err}", channel=channel)
    row = err.phoneme if isinstance(err.phoneme, int) else None
    name = phonemes[row] if row is not None and row < len(phonemes) else None
    message = str(err)
    if name is not None and err.parameter is not None:
        # The core's "phoneme <row>, parameter <p>: value <v> <reason>" with the phoneme's name.
        message = f"phoneme {name!r}, parameter {err.parameter}: value {_number(err.value)} {err.reason}"
    return ModelInputError(
        f"channel {channel!r}: {message}", channel=channel, utterance=err.utterance, segment=err.segment,
        phoneme=name, parameter=err.parameter, value=err.value, sample=err.sample, reason=err.reason,
    )


def _number(value: float | None) -> str:
    """A value as the core prints it (NaN, inf, 1.5)."""
    if value is None:
        return "None"
    if np.isnan(value):
        return "NaN"
    return str(value) if np.isfinite(value) else ("inf" if value > 0 else "-inf")


def _channel_phonemes(table: ParameterTable, channel: str, labels: Sequence[str], where: str) -> list[str]:
    phonemes = table.phonemes_for(channel)
    known = set(phonemes)
    for i, lab in enumerate(labels):
        if lab not in known:
            if lab in table.values:
                raise ModelInputError(
                    f"{where}: label {lab!r} (segment {i + 1}) has no parameters for channel {channel!r} in {table.source}",
                    channel=channel, segment=i, phoneme=lab, reason="no parameters for the channel",
                )
            raise ModelInputError(
                f"{where}: label {lab!r} (segment {i + 1}) is not a phoneme of {table.source} "
                f"(known: {' '.join(table.phonemes)})",
                channel=channel, segment=i, reason="not a phoneme of the table",
            )
    return phonemes


def trajectories(
    table: ParameterTable,
    labels: Sequence[str],
    starts: npt.ArrayLike,
    ends: npt.ArrayLike,
    times: npt.ArrayLike,
    channels: Sequence[str] | None = None,
    *,
    label_map: LabelMap | Mapping[str, str] | str | None = None,
) -> dict[str, F64]:
    """Channel trajectories of one utterance under the table's model.

    Parameters
    ----------
    table : ParameterTable
        Variant, per-channel constants and per-phoneme parameters.
    labels : sequence of str
        Segment labels, one per segment: the table's phonemes (pauses as ``"#"``), or, when the
        table records the label map it was fitted with, the corpus labels that map reads (e.g.
        ARPAbet ``AH0``); see ``label_map``.
    starts, ends : array_like of float
        Acoustic segment times in seconds: sorted, non-overlapping, end > start.
    times : array_like of float
        Times (s) at which to evaluate, e.g. ``np.arange(n) / fps``.
    channels : sequence of str, optional
        Channels to compute; default every channel of the table.
    label_map : LabelMap, dict, built-in name or file, optional
        Labels → phonemes. Default: the map the table was fitted with
        (``LabelMap.recorded(table)``; for a table that records none, the labels are its phonemes).
        ``LabelMap.identity(table.phonemes, ...)`` takes the labels as the table's phonemes.

    Returns
    -------
    dict
        ``channel -> ndarray[len(times)]``. Their Jacobians: ``coartic.jacobian.trajectory_jacobians``.

    Raises
    ------
    ModelInputError
        Unknown label, label without parameters for a channel, unsorted or overlapping
        segments, mismatched lengths, non-finite times.

    Examples
    --------
    >>> out = trajectories(table, ["#", "a", "p", "a", "#"], [0, .1, .25, .33, .5],
    ...                    [.1, .25, .33, .5, .6], np.arange(60) / 100, channels=["LLO"])
    >>> out["LLO"].shape
    (60,)
    """
    out: dict[str, F64] = {}
    for problem in utterance_channels(table, labels, starts, ends, times, channels, label_map=label_map):
        try:
            out[problem.channel] = _core.evaluate(problem.corpus, problem.params, problem.beta, problem.options)
        except ValueError as err:
            raise problem.error(err) from None
    return out


@dataclass(frozen=True)
class UtteranceChannel:
    """One channel of one utterance as the core takes it (what `trajectories` and the runtime
    evaluate; a whole fit's is `coartic.estimation.problem.ChannelProblem`): the corpus, the
    parameter rows (in ``phonemes`` order), beta and the options."""

    channel: str
    phonemes: list[str]
    corpus: _core.Corpus
    params: F64
    beta: float
    options: _core.ModelOptions

    def error(self, err: ValueError) -> ModelInputError:
        return core_error(err, self.channel, self.phonemes)


def utterance_channels(
    table: ParameterTable,
    labels: Sequence[str],
    starts: npt.ArrayLike,
    ends: npt.ArrayLike,
    times: npt.ArrayLike,
    channels: Sequence[str] | None = None,
    *,
    label_map: LabelMap | Mapping[str, str] | str | None = None,
) -> Iterator[UtteranceChannel]:
    """The labels mapped and checked, channel by channel (arguments as ``trajectories``); channels
    with the same phoneme rows share one corpus."""
    chans = list(table.channels) if channels is None else list(channels)
    # a table without a recorded map takes its phonemes as they are (the checks below name them)
    lmap = LabelMap.recorded(table) if label_map is None else resolve_label_map(label_map)
    if lmap is not None:
        try:
            labels = lmap.apply_labels(list(labels), "utterance")
        except DataError as err:
            raise ModelInputError(str(err)) from None
    # a table fitted with pause postures reads pauses as it was fitted (coartic.pauses)
    utt = utterances_for_table(table, [Utterance(labels, starts, ends, times)])[0]
    labels = list(utt.labels)
    corpora: dict[tuple[str, ...], _core.Corpus] = {}
    for ch in chans:
        table._check_channel(ch)
        phonemes = _channel_phonemes(table, ch, list(labels), "utterance")
        key = tuple(phonemes)
        if key not in corpora:
            corpora[key] = build_corpus([utt], phonemes)
        params, beta = table.to_matrix(ch, phonemes)
        yield UtteranceChannel(ch, phonemes, corpora[key], params, beta, model_options(table, ch))


def evaluate_corpus(table: ParameterTable, channel: str, utterances: Sequence[Utterance]) -> list[F64]:
    """One channel over many utterances in one core call; one array per utterance."""
    phonemes = table.phonemes_for(channel)
    corpus = build_corpus(utterances, phonemes)
    params, beta = table.to_matrix(channel, phonemes)
    try:
        values = _core.evaluate(corpus, params, beta, model_options(table, channel))
    except ValueError as err:
        raise core_error(err, channel, phonemes) from None
    bounds = np.cumsum([0] + [u.times.size for u in utterances])
    return [values[a:b] for a, b in zip(bounds[:-1], bounds[1:])]


def segment_weights(
    table: ParameterTable,
    channel: str,
    labels: Sequence[str],
    starts: npt.ArrayLike,
    ends: npt.ArrayLike,
    times: npt.ArrayLike,
) -> F64:
    """The weight of each segment's target in F: ``w_i(t) = ∂F/∂T_i = S_i R_i D_i / Σ_j R_j D_j``.

    These are the normalised dominance functions one draws under a trajectory
    (F = Σ_i T_i w_i). Computed by the core: each segment gets its own copy of its phoneme's
    parameters, so the target column of the Jacobian separates the segments.

    Returns
    -------
    ndarray [len(labels), len(times)]
    """
    phonemes = _channel_phonemes(table, channel, list(labels), "utterance")
    params, beta = table.to_matrix(channel, phonemes)
    row_of = {p: i for i, p in enumerate(phonemes)}
    per_segment = params[[row_of[lab] for lab in labels]]
    seg_names = [f"{lab}@{i}" for i, lab in enumerate(labels)]
    corpus = build_corpus([Utterance(seg_names, starts, ends, times)], seg_names)
    try:
        _, indptr, indices, data = _core.jacobian(corpus, per_segment, beta, model_options(table, channel))
    except ValueError as err:
        raise core_error(err, channel, seg_names) from None
    # the target columns (every N_PARAMS-th, beta's last column aside) of the core's CSR Jacobian
    rows = np.repeat(np.arange(indptr.size - 1), np.diff(indptr))
    target = (indices % N_PARAMS == 0) & (indices < len(labels) * N_PARAMS)
    weights = np.zeros((len(labels), indptr.size - 1))
    weights[indices[target] // N_PARAMS, rows[target]] = data[target]
    return weights
