"""The API documentation's examples run: the doctests of the estimator and the table modules, and
the README's estimator example (its ``pycon`` block), as a user would type them."""

from __future__ import annotations

import doctest
import re
from pathlib import Path

import pytest

import coartic.estimator
import coartic.table

README = Path(__file__).resolve().parents[2] / "README.md"


@pytest.mark.parametrize("module", [coartic.estimator, coartic.table], ids=lambda m: m.__name__)
def test_module_doctests(module: object) -> None:
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS, verbose=False)  # type: ignore[arg-type]
    assert result.attempted > 0 and result.failed == 0


def test_readme_estimator_example_runs() -> None:
    blocks = re.findall(r"```pycon\n(.*?)```", README.read_text(encoding="utf-8"), flags=re.S)
    assert blocks, "README.md has no pycon example"
    parser, runner = doctest.DocTestParser(), doctest.DocTestRunner(optionflags=doctest.ELLIPSIS)
    for i, text in enumerate(blocks):
        runner.run(parser.get_doctest(text, {}, f"README.md pycon block {i + 1}", str(README), 0))
    result = runner.summarize(verbose=False)
    assert result.attempted > 0 and result.failed == 0
