"""Bayesian estimation of the coarticulation parameters with emcee (docs/MCMC.md).

``coartic.mcmc.sample(spec, fit, out)`` is the whole job (``coartic mcmc`` is a thin shell over it).

job.py         the job as a library function: sample(), sample_table() (also batch's), McmcResult
posterior.py   the vectorised log-posterior (Rust batch SSE), priors, sampling coordinates
sampler.py     emcee ensembles in saved, resumable chunks, with a progress bar
convergence.py autocorrelation time, acceptance, R-hat and ESS: convergence is checked
summary.py     posterior quantiles into the parameter table's uncertainty fields
idata.py       each posterior's chains as ArviZ InferenceData (posterior.nc)
plots.py       corner, traces, posterior predictive band
mcmc_cli.py    `coartic mcmc SPEC --fit DIR --out DIR`
"""

from typing import Any

__all__ = ["sample", "McmcResult"]


def __getattr__(name: str) -> Any:
    # Lazy: the job imports matplotlib and the readers, which `import coartic.mcmc.sampler` need not.
    if name in __all__:
        from coartic.mcmc import job

        return getattr(job, name)
    raise AttributeError(name)
