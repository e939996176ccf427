"""What a batch run did (``BatchOutcome``): the units landed, skipped, failed, the workers.

Below both the run (``coartic.batch.run``, which fills it) and the report
(``coartic.batch.report``, which writes it into status.json and the report), so that neither
imports the other back.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from coartic.batch.tasks import UnitKey


@dataclass
class BatchOutcome:
    out: Path
    total: int  # units of the batch
    skipped: int  # finished by an earlier run
    landed: list[UnitKey] = field(default_factory=list)
    failed: dict[str, str] = field(default_factory=dict)  # unit label -> why
    interrupted: bool = False
    wall_s: float = 0.0
    workers: int = 0  # 0: serial
    threads: int | None = None  # rayon threads per worker

    @property
    def complete(self) -> bool:
        return not self.failed and not self.interrupted
