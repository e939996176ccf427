"""The estimation problem that least squares (``coartic.fit``), MCMC (``coartic.mcmc``) and the
batch share, below all of them: its settings, one channel's data, its parameters and their packing,
priors and shrinkage, per-utterance offsets and speakers, and the problem they make
(``problem.build_problem``, the one constructor). Estimation owns its inputs: ``build_problem``
takes ``settings.EstimationSettings``, which a fit spec builds (``FitSpec.estimation_settings()``)
and a Python user builds directly; nothing here imports a part above it, not even for an
annotation (tests/python/test_import_graph.py), and its errors are ``coartic.errors.SpecError``.

Modules (imported by name; this package imports none of them, so that importing one loads only
what it needs):

``settings``    EstimationSettings, ModelSettings, ParameterSettings, PriorSettings, GroupSettings,
                Override, Tie, Shrink; the defaults (DEFAULT_FREE, DEFAULT_FIT_BOUNDS, ...)
``data``        ChannelData, phoneme_inventory: a channel's utterances as the core's corpus
``packing``     Packing, Prior, moving: free entries, boxes, ties, the transform to x
``parameters``  ParameterSet: the settings as numbers (values, free, bounds, priors, standard errors);
                BoundNote
``bounds``      explain_bounds: why each fitted parameter at a bound is there
``penalties``   Penalty (priors), Shrinkage, ShrinkGroup, shrink_groups: extra residual rows
``offsets``     Offsets: per-utterance offsets profiled out
``speakers``    Speakers, SpeakerRows, utterance_speakers, affine_coefficients, expand_speaker_targets
``problem``     ChannelProblem, build_problem
"""
