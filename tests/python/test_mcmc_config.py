"""The [mcmc] table of a fit spec: every key read, every mistake named with the file and key."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from coartic.mcmc.errors import McmcConfigError
from coartic.mcmc.run import parse_config, phoneme_dir, walkers_for

SPEC = Path("fit/x.toml")


def test_defaults_and_every_key() -> None:
    default = parse_config(None, SPEC)
    assert (default.scope, default.noise, default.offsets, default.settings.moves) == ("phonemes", "free", "free", "de")
    assert parse_config({"offsets": "none"}, SPEC).offsets == "none"
    cfg = parse_config(
        {"scope": "channel", "phonemes": ["p", "tS"], "channels": ["LLO"], "noise": 0.12, "offsets": 0.02, "walkers": 40,
         "ensembles": 4, "chunk_steps": 250, "min_steps": 500, "max_steps": 9000, "seed": 3, "ball": 0.01,
         "plots": False, "moves": "stretch", "priors": {"LLO.p.k_r": [1.0, 0.05], "ULO.beta": [1, 0.2]}},
        SPEC,
    )
    assert (cfg.scope, cfg.phonemes, cfg.channels, cfg.noise, cfg.offsets, cfg.walkers, cfg.plots) == ("channel", ("p", "tS"), ("LLO",), 0.12, 0.02, 40, False)
    s = cfg.settings
    assert (s.n_ensembles, s.chunk_steps, s.min_steps, s.max_steps, s.seed, s.ball, s.moves) == (4, 250, 500, 9000, 3, 0.01, "stretch")
    assert cfg.priors == {"LLO": {"p.k_r": (1.0, 0.05)}, "ULO": {"beta": (1.0, 0.2)}}


@pytest.mark.parametrize(
    ("raw", "message"),
    [
        ({"walkerz": 3}, r"fit/x.toml: \[mcmc\] walkerz: unknown key"),
        ({"scope": "all"}, r"\[mcmc\] scope: 'all': expected one of phonemes, channel"),
        ({"noise": -1}, r"\[mcmc\] noise: -1: expected"),
        ({"noise": "auto"}, r"\[mcmc\] noise: 'auto'"),
        ({"offsets": 0}, r"\[mcmc\] offsets: 0: expected \"free\", \"none\" or a positive number"),
        ({"offsets": True}, r"\[mcmc\] offsets: True: expected"),
        ({"walkers": 2.5}, r"\[mcmc\] walkers: expected an integer >= 0"),
        ({"min_steps": 900, "max_steps": 800}, r"\[mcmc\] min_steps: 900 exceeds max_steps = 800"),
        ({"ball": 2}, r"\[mcmc\] ball: expected a number in \(0, 1\)"),
        ({"priors": {"p.k_r": [1, 0.1]}}, r"\[mcmc\] priors.p.k_r: expected a key \"CHANNEL.phoneme.parameter\""),
        ({"priors": {"LLO.p.k_r": [1, 0]}}, r"\[mcmc\] priors.LLO.p.k_r: sd must be positive"),
        ({"priors": {"LLO.p.k_r": "1"}}, r"\[mcmc\] priors.LLO.p.k_r: expected \[mean, sd\]"),
        ({"moves": "hmc"}, r"\[mcmc\] moves: unknown moves 'hmc'; expected one of de, de\+laplace, stretch"),
        ({"moves": "de-snooker"}, r"\[mcmc\] moves: moves = 'de-snooker' is no longer offered: emcee's DESnookerMove"),
        ({"phonemes": "p"}, r"\[mcmc\] phonemes: expected a list of strings"),
        # chains that cannot fit in memory: refused when the spec is read, naming the keys
        ({"max_steps": 10**9}, r"fit/x.toml: \[mcmc\] max_steps: max_steps = 1000000000 x walkers = 32 .* lower"),
        ({"walkers": 10**9}, r"fit/x.toml: \[mcmc\] walkers: max_steps = 20000 x walkers = 1000000000 .* lower"),
    ],
)
def test_mistakes_are_named(raw: dict[str, object], message: str) -> None:
    with pytest.raises(McmcConfigError, match=message):
        parse_config(raw, SPEC)


def test_walkers_and_directory_names() -> None:
    assert walkers_for(9, 0) == 32 and walkers_for(20, 0) == 42 and walkers_for(3, 13) == 14
    assert phoneme_dir("tS") == "tS" and phoneme_dir("#") == "x23" and phoneme_dir("a:") == "ax3a"


def test_offsets_follow_the_least_squares_model_unless_mcmc_says() -> None:
    """[model] offsets = τ (least squares with per-utterance offsets of sd τ) is the posterior's
    model too: τ fixed, unless [mcmc] offsets chooses otherwise; "none"/"free" keep the default."""
    from types import SimpleNamespace

    from coartic.estimation.settings import GroupSettings

    def fit(offsets: str | float) -> Any:  # the least-squares spec's [model] offsets (FitSpec.groups)
        return SimpleNamespace(groups=GroupSettings(offsets=offsets))

    assert parse_config(None, SPEC, fit(0.05)).offsets == 0.05
    assert parse_config({"walkers": 40}, SPEC, fit(0.05)).offsets == 0.05
    assert parse_config({"offsets": "none"}, SPEC, fit(0.05)).offsets == "none"
    assert parse_config(None, SPEC, fit("free")).offsets == "free"
    assert parse_config(None, SPEC, fit("none")).offsets == "free"


def test_every_mistake_is_reported_at_once() -> None:
    """The table is a schema (coartic.mcmc.config): several bad keys are named together, one a line."""
    with pytest.raises(McmcConfigError) as caught:
        parse_config({"scope": "all", "ball": 2, "plots": "yes"}, SPEC)
    assert str(caught.value).splitlines() == [
        "fit/x.toml: [mcmc] scope: 'all': expected one of phonemes, channel",
        "fit/x.toml: [mcmc] ball: expected a number in (0, 1), got 2",
        "fit/x.toml: [mcmc] plots: expected true or false, got 'yes'"]
