"""Perceptual tests of the animation (issue 27, item 4): `coartic perceive prepare | serve | export | analyse`.

One job per module: `spec` (the study's TOML), `stimuli` (the videos, from the runtime's face and
Festival's speech, with noise at set SNRs), `design` (each participant's trials: randomised,
counterbalanced, with attention checks, reproducible from the study's seed), `storage` (the results
database: SQLite by default, PostgreSQL by URL; every answer once), `server` (the participants' web
pages), `simulate` (answers of simulated participants with planted effects), `analysis` (mixed models,
confusion matrices, bootstrap intervals) and `report` (the HTML report). docs/PERCEIVE.md.
"""
