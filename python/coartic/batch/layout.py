"""Where a batch's results live in its output folder, and how a unit's folder lands there whole.

``coartic.batch.run`` writes units and ``coartic.batch.report`` assembles them: both read the
layout from here (it used to live in run.py, which made report and run import each other).
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

from coartic.batch.tasks import UnitKey

UNIT_FILE = "unit.json"


def unit_dir(out: Path, key: UnitKey) -> Path:
    # "_pooled" cannot be a group's name (spec.GROUP_NAME starts with a letter or digit).
    tree = "units" if key.kind == "fit" else "posteriors"
    return out / tree / (key.group if key.group is not None else "_pooled") / key.channel


def is_done(out: Path, key: UnitKey) -> bool:
    return (unit_dir(out, key) / UNIT_FILE).is_file()


def land_dir(target: Path, files: dict[str, bytes]) -> None:
    """Put ``files`` into the folder ``target`` whole: written into a temporary sibling folder,
    fsynced, then renamed; an existing ``target`` (an earlier assembly) is swapped out first."""
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.tmp-", dir=target.parent))
    try:
        for name, data in files.items():
            (tmp / name).parent.mkdir(parents=True, exist_ok=True)  # a posterior's chains sit in sub-folders
            with open(tmp / name, "wb") as f:
                f.write(data)
                f.flush()
                os.fsync(f.fileno())
        if target.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{target.name}.old-", dir=target.parent))
            os.rename(target, old / target.name)
            os.rename(tmp, target)
            shutil.rmtree(old)
        else:
            os.rename(tmp, target)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
