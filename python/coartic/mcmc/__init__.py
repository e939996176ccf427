"""Bayesian estimation of the coarticulation parameters with emcee (docs/MCMC.md).

posterior.py   the vectorised log-posterior (Rust batch SSE), priors, sampling coordinates
sampler.py     emcee ensembles in saved, resumable chunks, with a progress bar
convergence.py autocorrelation time, acceptance, R-hat and ESS: convergence is checked
summary.py     posterior quantiles into the parameter table's uncertainty fields
plots.py       corner, traces, posterior predictive band
mcmc_cli.py    `coartic mcmc SPEC --fit DIR --out DIR`
"""
