"""How well fitted tables predict data: the baselines, scores, held-out validation and comparison
of models (issue 28: evaluation beside fitting, apart from the least-squares fit itself).

- ``baselines``: the constant, step and warped-token baselines every held-out figure is set beside,
  and the "does not beat the step model" flag;
- ``heldout``: one split's scores (``SplitScore``), RMSE pooled over splits, the flags (below the
  fit's result and the report, which read them);
- ``score``: a table scored on utterances or recordings (``coartic score``: ``score_cli``);
- ``validate``: k-fold, held-out repetition / rate and time splits, each split fitted by the fit
  function it is given and scored;
- ``compare``: several fit specs side by side by held-out RMSE and AIC/BIC (``coartic compare``:
  ``compare_cli``).

The submodules are imported by name (``from coartic.evaluation.score import score_recordings``):
this package imports none of them, so importing one loads only what it needs.
"""
