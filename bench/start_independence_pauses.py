"""Start independence of the default spec held out, with pause postures (the default) and with one
pause label: fit German EMA 0024 (fit/ema_german_defaults_0024.toml, 32 starts) from θ starts of
15 and 100 (seeds 0 and 1), predict 0020, print each channel's held-out RMSE (mm).

    PYTHONPATH=python .venv/bin/python bench/start_independence_pauses.py | tee bench/results/start_independence_pauses.txt
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "python"))

from fit_helpers import EMA  # noqa: E402

from coartic.fit import load_spec  # noqa: E402
from coartic.jobs.fit import fit_job  # noqa: E402
from coartic.evaluation.score import score_recordings  # noqa: E402


def main() -> None:
    for pauses in ("postures", "one"):
        for starts, theta, seed in ((32, 15.0, 0), (32, 100.0, 1)):
            spec = load_spec(ROOT / "fit" / "ema_german_defaults_0024.toml")
            spec = spec.with_options(starts=starts, seed=seed, pauses=pauses,
                                     start={**spec.parameters.start, "theta_bw": theta, "theta_fw": theta})
            out = Path(tempfile.mkdtemp()) / "o"
            fit_job(spec, out, quiet=True, report=False)
            sc = score_recordings(out / "table.json", [EMA / "dfgspp_mo1_prosody_0020_ema.csv"],
                                  [EMA / "dfgspp_mo1_prosody_0020_Segment.tsv"])
            print(pauses, starts, theta, {r["channel"]: round(r["rmse_mm"], 3) for r in sc.channel_rows()},
                  flush=True)


if __name__ == "__main__":
    main()
