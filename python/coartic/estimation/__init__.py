"""The estimation problem that least squares (``coartic.fit``), MCMC (``coartic.mcmc``) and the
batch share, below all of them: one channel's data, its parameters and their packing, priors and
shrinkage, per-utterance offsets and speakers, and the problem they make (``problem.build_problem``,
the one constructor). Nothing here imports ``coartic.fit`` or ``coartic.mcmc``
(tests/python/test_import_graph.py): the spec (``coartic.fit.spec.FitSpec``) is read through its
attributes and named in annotations only, and its errors are ``coartic.errors.SpecError``.

Modules (imported by name; this package imports none of them, so that importing one loads only
what it needs):

``data``        ChannelData, phoneme_inventory: a channel's utterances as the core's corpus
``packing``     Packing, Prior, moving: free entries, boxes, ties, the transform to x
``parameters``  ParameterSet: a spec as numbers (values, free, bounds, priors, standard errors)
``penalties``   Penalty (priors), Shrinkage, ShrinkGroup, shrink_groups: extra residual rows
``offsets``     Offsets: per-utterance offsets profiled out
``speakers``    Speakers, SpeakerRows, utterance_speakers, affine_coefficients, expand_speaker_targets
``problem``     ChannelProblem, build_problem
"""
