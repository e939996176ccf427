"""How well fitted tables predict data: the baselines, scores, held-out validation, ``[choose]`` and
the comparison of models (issue 28: evaluation above fitting, apart from the least-squares fit
itself, below the application in ``coartic.jobs`` that runs and writes them).

- ``baselines``: the constant, step and warped-token baselines every held-out figure is set beside,
  and the "does not beat the step model" flag;
- ``heldout``: one split's scores (``SplitScore``), RMSE pooled over splits, the flags; ``Validation``,
  the scores as a fit's result carries them (through the fit's ``HeldOut`` protocol);
- ``score``: a table scored on utterances or recordings (``coartic score``: ``score_cli``);
- ``validate``: k-fold, held-out repetition / rate and time splits, each split fitted by the fit
  job it is given (``coartic.jobs.fit.fit_job``) and scored;
- ``choose``: a ``[choose]`` setting chosen by k-fold cross-validation on the training data;
- ``compare``: the rows of several fit specs side by side by held-out RMSE and AIC/BIC (the job
  that fits them: ``coartic.jobs.compare``; ``coartic compare``: ``coartic.jobs.compare_cli``).

The submodules are imported by name (``from coartic.evaluation.score import score_recordings``):
this package imports none of them, so importing one loads only what it needs.
"""
