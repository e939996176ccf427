"""emcee ensembles run in chunks that are saved as they finish, so that nothing is lost and a run resumes.

Storage (one directory per posterior): ``meta.json`` (coordinates, walkers, ensembles, seed and the
posterior's fingerprint) and ``ens<E>_chunk<K>.npz`` files, each with the chain and log-probabilities
of its steps, the accepted-move counts and the full sampler state at its end (walker positions,
log-probabilities, the Mersenne-Twister state emcee draws from). A chunk is written to a temporary
file, flushed to disk and renamed into place, so a chunk on disk is always whole. Chunks are
numbered from 0 without gaps: a chain is never spliced across a missing chunk, and a damaged
(truncated, empty) chunk is named in the error instead of being read around.

Ctrl-C (SIGINT) and ``kill`` (SIGTERM) during sampling save the steps done so far as one more
chunk before returning, so they lose nothing; ``kill -9`` loses at most the chunk in progress.
Running the same command again continues from the saved state, and because the random state is
saved too, the resumed chain is identical to one that was never interrupted.
"""

from __future__ import annotations

import json
import os
import re
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from coartic.extras import require
from coartic.mcmc import convergence, laplace
from coartic.mcmc.convergence import ConvergenceReport
from coartic.mcmc.errors import ChainError, McmcConfigError, McmcError
from coartic.mcmc.laplace import LaplaceProposal
from coartic.outputs import DeferredSignals, atomic_path, atomic_write_text

LogProb = Callable[[NDArray[np.float64]], NDArray[np.float64]]
Initial = Callable[[np.random.Generator, int], NDArray[np.float64]]

META = "meta.json"
_CHUNK = re.compile(r"^ens(\d+)_chunk(\d+)\.npz$")


MOVES = ("de", "de+laplace", "stretch")
# emcee 3.1.6's DESnookerMove does not leave the target invariant: alone it samples a 28-dimensional
# Gaussian with 0.64 of its standard deviation, and mixed 20 % with DEMove (this module's default
# until 2026-11) with 0.974 (bench/results/mcmc_moves.txt), so the 95 % intervals under-covered
# (docs/MCMC.md). It steps x' = z + (1 + γ e·(z1 - z2)) (x - z), a scaling about z
# whose factor has no inverse symmetry, and corrects with half the (d - 1) exponent.
REMOVED_MOVES = {"de-snooker": "emcee's DESnookerMove does not sample the posterior (intervals come out too narrow, docs/MCMC.md)"}
# "de+laplace": each step is, at random with these weights, the independence Metropolis-Hastings
# move from the posterior's Laplace approximation (coartic.mcmc.laplace) or emcee's DE move
LAPLACE = "laplace"
LAPLACE_WEIGHT = 0.5


def make_moves(name: str) -> Any:
    """emcee moves by name (the red-blue ones; "de+laplace" adds ``(LAPLACE, weight)``, the
    independence move that ``_Ensemble`` takes itself). "de" (default): differential evolution
    (ter Braak 2006), which on the correlated per-phoneme and channel posteriors has about a third of
    the stretch move's autocorrelation time at the same cost per step. "de+laplace": half the steps
    DE, half independence proposals from the Laplace approximation (coartic.mcmc.laplace): a half to
    a quarter of DE's autocorrelation time, but not fewer steps to convergence where the τ-stability
    check decides, and on the joint channel posteriors more CPU time (bench/results/mcmc_laplace.txt,
    docs/MCMC.md). "stretch": emcee's default."""
    require("mcmc", "MCMC sampling")
    import emcee

    check_moves(name)
    if name == "stretch":
        return None
    if name == "de+laplace":
        return [(emcee.moves.DEMove(), 1.0 - LAPLACE_WEIGHT), (LAPLACE, LAPLACE_WEIGHT)]
    return [(emcee.moves.DEMove(), 1.0)]


def check_moves(name: str) -> None:
    if name in REMOVED_MOVES:
        raise McmcConfigError(f"moves = {name!r} is no longer offered: {REMOVED_MOVES[name]}; use \"de\"")
    if name not in MOVES:
        raise McmcConfigError(f"unknown moves {name!r}; expected one of {', '.join(MOVES)}")


# [mcmc] scope: one posterior per phoneme per channel ("phonemes"), or one per channel
SCOPES: tuple[str, ...] = ("phonemes", "channel")


@dataclass
class SamplerSettings:
    """How long and how wide to sample. Defaults suit the ~10-dimensional per-phoneme posteriors."""

    n_walkers: int = 32
    n_ensembles: int = 3
    chunk_steps: int = 500  # steps per saved chunk and between convergence checks
    min_steps: int = 1000
    max_steps: int = 20000
    seed: int = 0
    ball: float = 1e-3  # initial ball radius, as a fraction of each coordinate's prior width
    moves: str = "de"

    def validate(self, dim: int) -> None:
        if self.n_walkers < 2 * dim + 2:
            raise McmcConfigError(f"n_walkers = {self.n_walkers} is too few for {dim} dimensions (emcee needs > 2 x dim; use >= {2 * dim + 2})")
        if self.n_walkers % 2:
            raise McmcConfigError(f"n_walkers = {self.n_walkers} must be even (emcee's stretch move splits walkers in halves)")
        for name in ("n_ensembles", "chunk_steps", "max_steps"):
            if getattr(self, name) < 1:
                raise McmcConfigError(f"{name} must be >= 1, got {getattr(self, name)}")
        check_moves(self.moves)
        if self.min_steps > self.max_steps:
            raise McmcConfigError(f"min_steps = {self.min_steps} exceeds max_steps = {self.max_steps}")
        self.check_memory(dim)

    def check_memory(self, dim: int, limit: int | None = None) -> None:
        """Refuse settings whose chains cannot fit in memory, naming the keys to lower.

        Every ensemble's whole chain and log-probabilities are held in memory (for the convergence
        checks), and emcee allocates each chunk in full before its first step."""
        limit = memory_limit() if limit is None else limit
        per_step = self.n_walkers * (dim + 1) * 8  # bytes: positions and log-probability
        whole = self.n_ensembles * self.max_steps * per_step
        chunk = 2 * min(self.chunk_steps, self.max_steps) * per_step  # emcee's backend + our copy
        if whole > limit:
            raise McmcConfigError(
                f"max_steps = {self.max_steps} x walkers = {self.n_walkers} x ensembles = {self.n_ensembles} in "
                f"{dim} dimensions needs {_size(whole)} for the chains, more than the {_size(limit)} this machine "
                "allows; lower [mcmc] max_steps, walkers or ensembles")
        if chunk > limit:
            raise McmcConfigError(
                f"chunk_steps = {self.chunk_steps} x walkers = {self.n_walkers} in {dim} dimensions needs "
                f"{_size(chunk)} per chunk, more than the {_size(limit)} this machine allows; lower [mcmc] chunk_steps or walkers")


def memory_limit() -> int:
    """Bytes the chains may take: half the machine's physical memory (16 GiB where unknown)."""
    try:
        return int(os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")) // 2
    except (ValueError, OSError, AttributeError):
        return 16 << 30


def _size(n: float) -> str:
    for unit in ("bytes", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if n < 1024 or unit == "PiB":
            return f"{n:.0f} {unit}" if unit == "bytes" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n} bytes"  # pragma: no cover


@dataclass
class Chunk:
    chain: NDArray[np.float64]  # (steps, walkers, dim)
    log_prob: NDArray[np.float64]  # (steps, walkers)
    accepted: NDArray[np.float64]  # (walkers,)
    coords: NDArray[np.float64]  # final state
    last_log_prob: NDArray[np.float64]
    random_state: tuple[Any, ...]


class ChainStore:
    """Chunked, append-only chain storage in one directory (see the module docstring)."""

    def __init__(self, directory: str | os.PathLike[str]) -> None:
        self.directory = Path(directory)

    def meta(self) -> dict[str, Any] | None:
        p = self.directory / META
        if not p.exists():
            return None
        try:
            return dict(json.loads(p.read_text()))
        except (OSError, json.JSONDecodeError) as exc:
            raise ChainError(f"{p}: unreadable chain metadata ({exc}); delete the directory to start over") from exc

    def open(self, meta: dict[str, Any]) -> None:
        """Create the store, or check that an existing one holds chains of the same posterior and settings."""
        old = self.meta()
        if old is None:
            self.directory.mkdir(parents=True, exist_ok=True)
            atomic_write_text(self.directory / META, json.dumps(meta, indent=1))
            return
        for key in ("fingerprint", "coordinates", "n_walkers", "n_ensembles", "seed", "moves"):
            if old.get(key) != meta.get(key):
                raise ChainError(
                    f"{self.directory}: holds chains of a different run ({key}: saved {old.get(key)!r}, now {meta.get(key)!r}); "
                    "use another output directory, or delete this one to start over"
                )

    def chunk_paths(self, ensemble: int) -> list[Path]:
        """The ensemble's chunks in order; refuses a gap (a chain must not be spliced across it)."""
        if not self.directory.exists():
            return []
        found = []
        for p in self.directory.iterdir():
            m = _CHUNK.match(p.name)
            if m and int(m.group(1)) == ensemble:
                found.append((int(m.group(2)), p))
        found.sort()
        for expected, (k, p) in enumerate(found):
            if k != expected:
                later = [q.name for j, q in found if j > expected]
                raise ChainError(
                    f"{self.directory / f'ens{ensemble:02d}_chunk{expected:05d}.npz'}: missing, but later chunks exist "
                    f"({', '.join(later)}); the chain cannot continue across the gap. Delete the later chunks to resume "
                    f"from chunk {expected - 1}, or delete {self.directory} to start over" if expected else
                    f"{self.directory / f'ens{ensemble:02d}_chunk00000.npz'}: missing, but later chunks exist "
                    f"({', '.join(later)}); delete {self.directory} to start over")
        return [p for _, p in found]

    def append(self, ensemble: int, chunk: Chunk) -> Path:
        k = len(self.chunk_paths(ensemble))  # no gaps, so the next number is free
        path = self.directory / f"ens{ensemble:02d}_chunk{k:05d}.npz"
        if path.exists():  # pragma: no cover - only if another process writes the same store
            raise ChainError(f"{path}: already exists; another run is writing {self.directory}")
        rs = chunk.random_state
        with atomic_path(path) as tmp:  # fsync, then rename: a chunk on disk is whole after a crash
            np.savez(
                tmp,
                chain=chunk.chain,
                log_prob=chunk.log_prob,
                accepted=chunk.accepted,
                coords=chunk.coords,
                last_log_prob=chunk.last_log_prob,
                rs_keys=np.asarray(rs[1], dtype=np.uint32),
                rs_scalars=np.array([rs[2], rs[3]], dtype=np.int64),
                rs_gauss=np.array([rs[4]], dtype=np.float64),
            )
        return path

    def load(self, ensemble: int, dim: int, n_walkers: int) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], Chunk | None]:
        """(chain, log_prob, accepted counts, last chunk or None) of one ensemble."""
        chains, lps = [], []
        accepted = np.zeros(n_walkers)
        last: Chunk | None = None
        paths = self.chunk_paths(ensemble)
        for i, p in enumerate(paths):
            try:
                if p.stat().st_size == 0:
                    raise ChainError("the file is empty")
                with np.load(p) as z:
                    last = Chunk(
                        chain=z["chain"],
                        log_prob=z["log_prob"],
                        accepted=z["accepted"],
                        coords=z["coords"],
                        last_log_prob=z["last_log_prob"],
                        random_state=("MT19937", z["rs_keys"], int(z["rs_scalars"][0]), int(z["rs_scalars"][1]), float(z["rs_gauss"][0])),
                    )
            except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
                # (an empty .npz raises EOFError, which the command line would turn into a bare "Aborted!")
                after = [q.name for q in paths[i + 1:]]
                what = f"delete it and the {len(after)} chunk(s) after it ({', '.join(after)})" if after else "delete it"
                raise ChainError(f"{p}: damaged chain chunk ({type(exc).__name__}: {exc}); {what} to resume from "
                                 "the chunk before, or delete the directory to start over") from exc
            if last.chain.ndim != 3 or last.chain.shape[1:] != (n_walkers, dim):
                raise ChainError(f"{p}: chain shaped {last.chain.shape}, expected (steps, {n_walkers}, {dim})")
            bad = ~np.isfinite(last.chain)
            if bad.any() or not np.isfinite(last.coords).all():
                # a walker is always at a finite point: NaN is damage (emcee would resume from it and
                # fail on the ensemble's covariance with a message about condition numbers)
                step, walker, _ = (int(v) for v in np.argwhere(bad)[0]) if bad.any() else (last.chain.shape[0], 0, 0)
                after = [q.name for q in paths[i + 1:]]
                what = f"delete it and the {len(after)} chunk(s) after it ({', '.join(after)})" if after else "delete it"
                raise ChainError(f"{p}: damaged chain chunk (non-finite walker positions, the first at step {step}, "
                                 f"walker {walker}); {what} to resume from the chunk before, or delete the directory "
                                 "to start over")
            chains.append(last.chain)
            lps.append(last.log_prob)
            accepted += last.accepted
        if not chains:
            return np.empty((0, n_walkers, dim)), np.empty((0, n_walkers)), accepted, None
        return np.concatenate(chains), np.concatenate(lps), accepted, last


@dataclass
class SamplingResult:
    names: list[str]  # coordinate names
    chains: list[NDArray[np.float64]]  # per ensemble (steps, walkers, dim)
    log_probs: list[NDArray[np.float64]]
    acceptance: list[float]
    report: ConvergenceReport | None
    interrupted: bool = False
    history: list[dict[str, float]] = field(default_factory=list)  # tau_max per check

    @property
    def converged(self) -> bool:
        return bool(self.report is not None and self.report.converged and not self.interrupted)

    def draws(self) -> NDArray[np.float64]:
        """Post-burn-in, thinned draws of all ensembles and walkers, (n_draws, dim)."""
        burn, thin = (self.report.burn_in, self.report.thin) if self.report else (len(self.chains[0]) // 2, 1)
        return np.concatenate([c[burn::thin].reshape(-1, c.shape[2]) for c in self.chains])


def _run_chunk(
    log_prob: LogProb,
    coords: NDArray[np.float64],
    last_lp: NDArray[np.float64] | None,
    random_state: tuple[Any, ...],
    steps: int,
    on_step: Callable[[], None],
    moves: str = "de",
    proposal: LaplaceProposal | None = None,
) -> tuple[Chunk | None, bool]:
    """Advance one ensemble by ``steps``; on KeyboardInterrupt return the steps done so far and True.

    Only whole steps are kept, each with the random state right after it, so that the resumed
    chain equals an uninterrupted one.

    The steps are emcee's (``EnsembleSampler.sample`` with its red-blue moves), taken by
    ``_Ensemble.step``: the same draws from the same generator in the same order, so the chains
    are emcee's to the bit, without the per-walker Python loops of emcee's step (the acceptance
    test, the log-probabilities' blob handling), a third of a step's cost on a cheap posterior.
    With "de+laplace" some steps are the Laplace proposal's independence move instead (``proposal``;
    None: DE alone, as when the approximation could not be built).
    """
    stop = False

    def guarded(x: NDArray[np.float64]) -> NDArray[np.float64]:
        # An interrupt inside the log-probability finishes the step with every proposal rejected
        # (that step is then dropped) instead of escaping through the sampler, which would print
        # the walkers' parameters and a traceback on the way out.
        nonlocal stop
        if not stop:
            try:
                return log_prob(x)
            except KeyboardInterrupt:
                stop = True
        return np.full(np.atleast_2d(x).shape[0], -np.inf)

    n_walkers, dim = coords.shape
    ensemble = _Ensemble(guarded, moves, random_state, proposal)
    chain = np.empty((steps, n_walkers, dim))
    lps = np.empty((steps, n_walkers))
    accepted = np.zeros(n_walkers)
    # (whole steps, accepted counts, random state after them): replaced as one, so an interrupt
    # anywhere leaves a consistent record of the steps done
    kept: tuple[int, NDArray[np.float64], tuple[Any, ...]] = (0, accepted, random_state)
    interrupted = False
    try:
        lp = ensemble.start(coords, last_lp)
        for i in range(steps):
            coords, lp, acc = ensemble.step(coords, lp)
            if stop:
                break
            chain[i] = coords
            lps[i] = lp
            kept = (i + 1, kept[1] + acc, ensemble.random_state())
            on_step()
    except KeyboardInterrupt:  # raised outside the log-probability
        interrupted = True
    interrupted = interrupted or stop
    good, accepted, state = kept
    if good == 0:
        return None, interrupted
    return (
        Chunk(
            chain=chain[:good],
            log_prob=lps[:good],
            accepted=accepted,
            coords=chain[good - 1].copy(),
            last_log_prob=lps[good - 1].copy(),
            random_state=state,
        ),
        interrupted,
    )


class _Ensemble:
    """emcee's ensemble step (``EnsembleSampler.sample`` with ``RedBlueMove.propose``), vectorised.

    Every draw is emcee's, from a ``RandomState`` in emcee's order: per step the choice of move,
    the shuffle of the walkers into halves, per half the move's proposal and one uniform per walker
    for the acceptance test (drawn as one array: the same numbers, the same logarithms). The
    initial checks are emcee's too, with its messages (independent walkers, no NaN).

    The independence move (``LAPLACE``, coartic.mcmc.laplace) is not emcee's: all walkers propose
    from the fixed ``proposal`` at once, one uniform each for the acceptance test.
    """

    def __init__(self, log_prob: LogProb, moves: str, random_state: tuple[Any, ...],
                 proposal: LaplaceProposal | None = None) -> None:
        require("mcmc", "MCMC sampling")
        import emcee

        made = make_moves(moves)
        pairs = [(emcee.moves.StretchMove(), 1.0)] if made is None else made
        if proposal is None:  # no approximation: the red-blue moves alone
            pairs = [(m, w) for m, w in pairs if m != LAPLACE]
        self.proposal = proposal
        self.moves = [m for m, _ in pairs]
        for m in self.moves:
            if m != LAPLACE and not isinstance(m, emcee.moves.RedBlueMove):  # pragma: no cover - make_moves gives red-blue moves
                raise McmcError(f"{type(m).__name__}: not a red-blue move")
        weights = np.array([w for _, w in pairs], dtype=np.float64)
        self.weights = weights / weights.sum()
        self.log_prob = log_prob
        self.random = np.random.RandomState()
        self.random.set_state(random_state)
        self._walkers_independent = emcee.ensemble.walkers_independent

    def random_state(self) -> tuple[Any, ...]:
        """The generator's state as emcee keeps it (and the chunks store it)."""
        state = self.random.get_state(legacy=True)
        if not isinstance(state, tuple):  # pragma: no cover - MT19937's legacy state is a tuple
            raise McmcError(f"unexpected random state {type(state).__name__}")
        return state

    def log_probs(self, coords: NDArray[np.float64]) -> NDArray[np.float64]:
        """emcee's ``compute_log_prob`` for a log-probability returning one float per walker."""
        if np.any(np.isinf(coords)):
            raise ChainError("At least one parameter value was infinite")
        if np.any(np.isnan(coords)):
            raise ChainError("At least one parameter value was NaN")
        lp = np.array(self.log_prob(coords), dtype=np.float64).reshape(len(coords))
        if np.any(np.isnan(lp)):
            raise ChainError("Probability function returned NaN")
        return lp

    def start(self, coords: NDArray[np.float64], last_lp: NDArray[np.float64] | None) -> NDArray[np.float64]:
        if not self._walkers_independent(coords):
            raise ChainError("Initial state has a large condition number. Make sure that your walkers are "
                             "linearly independent for the best performance")
        if last_lp is None:
            last_lp = self.log_probs(coords)
        if np.any(np.isnan(last_lp)):
            raise ChainError("The initial log_prob was NaN")
        return np.array(last_lp, dtype=np.float64)

    def step(self, coords: NDArray[np.float64], lp: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """One step from (coords, lp): the new positions and log-probabilities (new arrays) and which walkers moved."""
        random = self.random
        move = self.moves[random.choice(len(self.moves), p=self.weights)]
        if isinstance(move, str):
            return self.independence(coords, lp)
        coords, lp = coords.copy(), lp.copy()
        n_walkers = len(coords)
        move.setup(coords)
        accepted = np.zeros(n_walkers, dtype=bool)
        inds = np.arange(n_walkers) % move.nsplits
        if move.randomize_split:
            random.shuffle(inds)
        for split in range(move.nsplits):
            subset = inds == split
            sets = [coords[inds == j] for j in range(move.nsplits)]
            q, factors = move.get_proposal(sets[split], sets[:split] + sets[split + 1:], random)
            new_lp = self.log_probs(q)
            # emcee: for each walker of the half in turn, accept if f + lp' - lp > log(u), u = random.rand()
            moved = factors + new_lp - lp[subset] > np.log(random.rand(len(q)))
            accepted[subset] = moved
            into = subset & accepted
            coords[into] = q[moved]
            lp[into] = new_lp[moved]
        return coords, lp, accepted.astype(np.float64)

    def independence(self, coords: NDArray[np.float64], lp: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Every walker's independence Metropolis-Hastings step from the proposal q: accept x' if
        log q(x) - log q(x') + lp' - lp > log u (coartic.mcmc.laplace, detailed balance)."""
        assert self.proposal is not None
        q, inside = self.proposal.draw(self.random, len(coords))
        new_lp = np.full(len(q), -np.inf)
        if inside.any():
            new_lp[inside] = self.log_probs(q[inside])
        with np.errstate(invalid="ignore"):
            factors = self.proposal.log_density(coords) - self.proposal.log_density(q)
            moved = (factors + new_lp - lp > np.log(self.random.rand(len(q)))) & inside
        coords, lp = coords.copy(), lp.copy()
        coords[moved] = q[moved]
        lp[moved] = new_lp[moved]
        return coords, lp, moved.astype(np.float64)


def laplace_proposal(store: ChainStore, settings: SamplerSettings, log_prob: LogProb, start: NDArray[np.float64] | None,
                     bounds: tuple[NDArray[np.float64], NDArray[np.float64]] | None) -> LaplaceProposal | None:
    """The chains' Laplace proposal for "de+laplace": the saved one (a resumed run uses the very
    same), or built from ``start`` (a fresh run) and saved; None for other moves, and when the
    approximation cannot be built (the chains then take DE steps alone, and the file says why)."""
    if settings.moves != "de+laplace":
        return None
    if start is None:
        return laplace.LaplaceProposal.load(store.directory, len((store.meta() or {})["coordinates"]))
    lower, upper = bounds if bounds is not None else (None, None)
    try:
        proposal: LaplaceProposal | None = laplace.build(log_prob, start, lower, upper)
    except laplace.ProposalError as exc:
        laplace.save_failure(store.directory, str(exc))
        return None
    assert proposal is not None
    proposal.save(store.directory)
    return proposal


def run(
    log_prob: LogProb,
    initial: Initial,
    names: Sequence[str],
    out: str | os.PathLike[str],
    settings: SamplerSettings,
    fingerprint: str = "",
    progress: bool = True,
    label: str = "",
    stop_when_converged: bool = True,
    bounds: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None,
) -> SamplingResult:
    """Sample until converged (convergence.check) or ``max_steps``, resuming whatever ``out`` holds.

    ``initial(rng, n_walkers)`` gives starting positions for a fresh ensemble. ``bounds``: the
    support's (lower, upper), for the Laplace proposal of "de+laplace" (coartic.mcmc.laplace; it
    starts from the mean of the first ensemble's initial positions). Returns the chains, the last
    convergence report and whether the run was interrupted.
    """
    dim = len(names)
    settings.validate(dim)
    # Import the diagnostics' heavy dependencies now: a Ctrl-C that lands inside an extension
    # module's import turns into an ImportError instead of a KeyboardInterrupt.
    convergence.load_arviz()
    store = ChainStore(out)
    store.open(
        {
            "coordinates": list(names),
            "n_walkers": settings.n_walkers,
            "n_ensembles": settings.n_ensembles,
            "seed": settings.seed,
            "moves": settings.moves,
            "fingerprint": fingerprint,
        }
    )
    W, E = settings.n_walkers, settings.n_ensembles
    chains: list[NDArray[np.float64]] = []
    lps: list[NDArray[np.float64]] = []
    accepted: list[NDArray[np.float64]] = []
    # per ensemble: walker positions, their log-probabilities (None before the first step), random state
    states: list[tuple[NDArray[np.float64], NDArray[np.float64] | None, Any]] = []
    for e in range(E):
        c, lp, acc, last = store.load(e, dim, W)
        chains.append(c)
        lps.append(lp)
        accepted.append(acc)
        if last is None:
            rng = np.random.default_rng([settings.seed, e])
            coords = np.asarray(initial(rng, W), dtype=np.float64)
            if coords.shape != (W, dim):
                raise McmcError(f"initial positions shaped {coords.shape}, expected ({W}, {dim})")
            rs = np.random.RandomState(np.random.SeedSequence([settings.seed, e, 1]).generate_state(4)).get_state()
            states.append((coords, None, rs))
        else:
            states.append((last.coords, last.last_log_prob, last.random_state))
    fresh = states[0][1] is None and len(chains[0]) == 0
    proposal = laplace_proposal(store, settings, log_prob, states[0][0].mean(axis=0) if fresh else None, bounds)

    history: list[dict[str, float]] = []
    report: ConvergenceReport | None = None
    interrupted = False

    def diagnose(skip_when_short: bool = False) -> ConvergenceReport | None:
        """The checks between chunks skip what cannot change their decision (convergence.check);
        the report returned with the chains is always complete."""
        n = min(len(c) for c in chains)
        if n < 4:
            return None
        acc = [float(np.mean(a)) / len(c) for a, c in zip(accepted, chains)]
        r = convergence.check([c[:n] for c in chains], acc, names, skip_when_short=skip_when_short)
        if not history or history[-1]["steps"] != n:  # a partial report completed: one check
            history.append({"steps": float(n), "tau_max": r.tau_max})
        return r

    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    from coartic.console import LineProgress

    columns = [
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[status]}"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
    ]
    with LineProgress(*columns, console=Console(stderr=True), quiet=not progress) as bar, DeferredSignals() as signals:
        task = bar.add_task(label or "sampling", total=E * settings.max_steps, completed=sum(len(c) for c in chains), status="")

        def loop() -> bool:
            """Sample chunk after chunk; True if interrupted."""
            nonlocal report
            while True:
                n = min(len(c) for c in chains)
                if n >= max(settings.min_steps, 4) and (report is None or report.n_steps != n):
                    with signals.saving():  # a Ctrl-C here waits until the check is done
                        report = diagnose(skip_when_short=True)
                    if report is not None:
                        bar.update(task, status=f"tau {report.tau_max:.0f}, N/tau {n / max(report.tau_max, 1e-9):.0f}")
                        if stop_when_converged and report.converged:
                            return False
                if n >= settings.max_steps:
                    return False
                for e in range(E):
                    # at most one chunk, and lagging ensembles (after an interrupt) catch up first
                    todo = min(settings.chunk_steps, settings.max_steps - len(chains[e]), n + settings.chunk_steps - len(chains[e]))
                    if todo <= 0:
                        continue
                    coords, last_lp, rs = states[e]
                    chunk, stopped = _run_chunk(log_prob, coords, last_lp, rs, todo, lambda: bar.advance(task), settings.moves, proposal)
                    if chunk is not None:
                        with signals.saving():
                            store.append(e, chunk)
                            chains[e] = np.concatenate([chains[e], chunk.chain])
                            lps[e] = np.concatenate([lps[e], chunk.log_prob])
                            accepted[e] = accepted[e] + chunk.accepted
                            states[e] = (chunk.coords, chunk.last_log_prob, chunk.random_state)
                    if stopped:
                        return True

        try:
            interrupted = loop()
        except KeyboardInterrupt:  # outside a chunk (e.g. during a convergence check): every chunk is saved
            interrupted = True
    n = min(len(c) for c in chains)
    if report is None or report.n_steps != n or report.partial:
        report = diagnose()
    acceptance = [float(np.mean(a)) / max(len(c), 1) for a, c in zip(accepted, chains)]
    return SamplingResult(list(names), chains, lps, acceptance, report, interrupted, history)
