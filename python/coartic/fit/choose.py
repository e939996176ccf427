"""A setting's grid and value for ``[choose]`` (``coartic fit --choose``), on the spec: ``parse_choose``
makes the grid, ``set_value`` the spec of one value (the fits of a grid, of ``coartic compare --vary``,
of the posterior at a chosen value). The choice itself, by k-fold cross-validation on the training
data, is an evaluation: ``coartic.evaluation.choose``.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from coartic.errors import SpecError
from coartic.fit.spec import CHOOSABLE, FitSpec, choose_base, make_choose, parse_grid


def set_value(spec: FitSpec, key: str, value: float) -> FitSpec:
    """The spec with the setting ``key`` at ``value`` and no ``[choose]`` (the fits of a grid)."""
    base = choose_base(key)
    if base == "shrink.sd":
        table = None if key == "shrink.sd" else key[: -len(".sd")]
        shrinks = tuple(replace(s, sd=float(value)) if table in (None, s.key) else s for s in spec.priors.shrinks)
        return spec.with_options(shrinks=shrinks, choose=None)
    if base == "prior_noise":
        return spec.with_options(prior_noise=float(value), choose=None)
    if base == "plateau_fraction":
        return spec.with_options(plateau_fraction=float(value), choose=None)
    if base == "target_prior":
        return spec.with_options(target_prior=float(value), choose=None)
    raise SpecError.at(spec.path, "choose.key", f"{key!r}: not a setting cross-validation can choose")


def parse_choose(spec: FitSpec, text: str) -> FitSpec:
    """``coartic fit --choose KEY=V1,V2,...``: the spec with that grid (group, folds and rule from
    the spec's ``[choose]``, else by utterance, 5 folds, and 1-SE for a strength)."""
    key, values = parse_grid("--choose", text, "shrink.sd=0.03,0.1,0.3,1")
    grid: list[Any] = []
    for v in values:
        try:
            grid.append(float(v))
        except ValueError:
            raise SpecError(f"--choose {text!r}: {v!r} is not a number") from None
    c = spec.choose
    base = choose_base(key)
    rule = c.rule if c is not None else ("1se" if base is not None and CHOOSABLE[base] != 0 else "min")
    made = make_choose(spec.path, key, grid, c.group if c else "utterance", c.folds if c else 5, rule,
                       spec.priors.shrinks, "--choose")
    return spec.with_options(choose=made)
