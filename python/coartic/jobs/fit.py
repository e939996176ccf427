"""The fit job: fit a spec, choose its ``[choose]`` setting, validate it on held-out data, write
everything (``coartic fit SPEC --out DIR`` runs this in its staging directory).

The fitting library (``coartic.fit.runner.run``) returns a result and writes nothing; this job
saves the result after every channel (through ``run``'s ``on_channel``), so an interrupted run keeps
what it finished, then adds the validation (``coartic.evaluation.validate``, each split fitted by
this job into ``validation/``) and the HTML report (``coartic.report.html``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

from rich.console import Console

from coartic.errors import SpecError
from coartic.evaluation.choose import cross_validate
from coartic.evaluation.heldout import Validation
from coartic.fit.result import FitResult
from coartic.fit.runner import FitFailed, run
from coartic.fit.spec import FitSpec, load_spec
from coartic.model import Utterance


def fit_job(spec: FitSpec | str | Path, out: str | Path | None = None, *,
            utterances: Sequence[Utterance] | None = None, console: Console | None = None, quiet: bool = False,
            validate: bool = False, report: bool = True) -> FitResult:
    """Fit every channel of ``spec`` (``coartic.fit.runner.run``) and return the FitResult; with
    ``out``, write everything there.

    ``out`` receives what ``coartic fit SPEC --out DIR`` writes (the command calls this):
    ``table.json``/``table.csv``, ``rmse.csv``, ``parameters.csv``, ``fit_report.txt``,
    ``fitted.npz``, ``summary.json``, with ``report=True`` the HTML report and its figures, and
    with ``validate=True`` the held-out fits in ``validation/`` (their scores also in
    ``result.validation``). The result is written after every channel, so an interrupted run keeps
    what it finished.

    ``utterances`` skips loading (e.g. a validation split of already loaded data).

    Raises
    ------
    FitFailed
        An engine failed on a channel (nothing is written for it); names the channel.
    SpecError, DataError
        A spec or data problem, naming the file and key.
    """
    if not isinstance(spec, FitSpec):
        spec = load_spec(spec)
    console = console or Console(stderr=True, quiet=quiet)
    target = None if out is None else Path(out)

    def save(result: FitResult) -> None:
        if target is not None:
            result.save(target)

    try:
        result = run(spec, utterances=utterances, console=console, quiet=quiet, on_channel=save,
                     choose=cross_validate)
    except FitFailed as e:
        if target is None:
            raise
        raise FitFailed(f"{e}; nothing was written for {e.channel}", channel=e.channel) from None
    if validate and result.channels and not result.interrupted:
        from coartic.evaluation.validate import validate_all

        try:
            # the splits fitted by this job (into validation/<split>/), of the utterances the fit had
            scores = validate_all(spec, None if target is None else target / "validation",
                                  utterances=result.utterances, console=console, quiet=quiet, notes=result.notes,
                                  fit=fit_job)
            result.validation = Validation(scores)
        except KeyboardInterrupt:
            result.notes.append("validation interrupted by the user")
        except SpecError as e:  # e.g. no repetition or rate to hold out: said, not raised
            result.notes.append(f"no validation: {e}")
    if target is not None:
        result.save(target)
        if report and result.channels:
            from coartic.report.html import write_report

            result.report = write_report(result, target, console=None if quiet else console)
    return result
