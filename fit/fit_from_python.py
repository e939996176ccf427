"""The fit from Python, for scripts and notebooks: one call, then the result's pieces.

    .venv/bin/python fit/fit_from_python.py fit/synthetic.toml results/synthetic_py [LLO,ULO]

Copy and adapt: pick channels, change the engine, look at parameters and their standard errors.
"""

from __future__ import annotations

import sys

from coartic.fit.spec import load_spec
from coartic.jobs.fit import fit_job


def main(spec_path: str, out: str, channels: str | None) -> None:
    spec = load_spec(spec_path)
    if channels:
        spec = spec.with_options(channels=tuple(channels.split(",")))
    result = fit_job(spec, out)  # fits, and writes table.json, rmse.csv, ... into `out`
    # (coartic.fit.run(spec) fits and returns the same result without writing anything)
    for row in result.rmse_rows():
        if row["group"] in ("all", "vowel"):
            print(f"{row['channel']:4} {row['group']:6} {row['value']:4} RMSE {row['rmse_mm']:.3f} mm")
    for ch, fit in result.channels.items():
        st = fit.stats
        assert st is not None
        i = st.names.index("p.k_r") if "p.k_r" in st.names else None
        if i is not None:
            print(f"{ch}: k_R of /p/ = {st.values[i]:.3f} +/- {st.stderr[i]:.3f}")
    table = result.table()  # a coartic.table.ParameterTable, ready for coartic.trajectories
    print("phonemes:", " ".join(table.phonemes))


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "fit/synthetic.toml",
         sys.argv[2] if len(sys.argv) > 2 else "results/synthetic_py",
         sys.argv[3] if len(sys.argv) > 3 else None)
