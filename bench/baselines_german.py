"""The real German EMA against its baselines (issue 19 item 4): does the fitted model beat the
constant (training mean) and the step model (each phoneme's training mean, no coarticulation)?

With the product's own fit (``coartic.fit.run``, fit/ema_german.toml's settings: modified model,
target, alpha, theta_bw, theta_fw and k_r free, staged) and scorer (``coartic.evaluation.score``, the
baselines of ``coartic.evaluation.baselines`` on exactly the same samples), on the two utterances of
tests/data/realdata/emu-ema-german (speaker mo1, LA and JO):

1. **Another sentence**: fit utterance 0024 alone (fit/ema_german_0024.toml), predict 0020. This is
   what ``coartic fit fit/ema_german_0024.toml`` then ``coartic score TABLE 0020 --labels ...``
   print. The reverse (fit 0020, predict 0024) cannot be scored: 0024 has /u v/, which 0020 lacks,
   and 0020 lacks their fallbacks /o f/ too.
2. **Split in time**: each utterance cut at its middle segment; fit the first halves of both,
   predict the second halves. Phonemes the first halves lack are scored as their phonetic class's
   fallback of the german_sampa label map (as ``coartic score`` does; listed in the output).

There is no other token of either sentence (no repetition, no other rate), so the warped-token
baseline does not apply here. Output in bench/results/baselines_german.txt:

    .venv/bin/python bench/baselines_german.py
"""

from __future__ import annotations

import sys
import time
from pathlib import Path


from coartic.fit import load_spec, run
from coartic.fit.data import load_utterances
from coartic.evaluation.score import Score, score_utterances, with_fallbacks
from coartic.io.labelmap import LabelMap
from coartic.evaluation.validate import halves  # noqa: F401  (bench/real_data.py imports it from here)

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "bench" / "results" / "baselines_german.txt"


def lines(title: str, sc: Score) -> list[str]:
    out = [f"## {title}", *(f"note: {n}" for n in sc.notes),
           f"{'channel':8s}{'model':10s}{'as measured':>13s}{'offset removed':>16s}{'speaker-calibrated':>20s}{'samples':>9s}"]
    for r in sc.baseline_rows():
        out.append(f"{r['channel']:8s}{r['model']:10s}{r['rmse_mm']:13.3f}{r['rmse_offset_removed_mm']:16.3f}"
                   f"{r['rmse_calibrated_mm']:20.3f}{r['samples']:9d}")
    out += [f"WORSE THAN THE STEP MODEL: {f}" for f in sc.flags()] or ["the table beats the step model on every channel"]
    return out + [""]


def main() -> int:
    t0 = time.perf_counter()
    report = ["# The German EMA against its baselines (bench/baselines_german.py)",
              "RMSE in mm; baselines fitted on the same training data, scored on the same samples.", ""]
    both = load_spec(ROOT / "fit" / "ema_german.toml")
    utts = load_utterances(both)
    by_id = {u.name.rsplit("_", 2)[-2]: u for u in utts}  # "0020", "0024"

    one = load_spec(ROOT / "fit" / "ema_german_0024.toml")
    res = run(one, quiet=True)
    test, note = with_fallbacks([by_id["0020"]], res.table(), one.channels, LabelMap.builtin("german_sampa"))
    sc = score_utterances(res.table(), test, one.channels, train=[by_id["0024"]])
    sc.notes += [note] if note else []
    report += lines("1. another sentence: fit 0024 (fit/ema_german_0024.toml), predict 0020", sc)

    first, second = zip(*(halves(u) for u in utts))
    res = run(both, utterances=list(first), quiet=True)
    test, note = with_fallbacks(list(second), res.table(), both.channels, LabelMap.builtin("german_sampa"))
    sc = score_utterances(res.table(), test, both.channels, train=list(first))
    sc.notes += [note] if note else []
    report += lines("2. split in time: fit the first halves of 0020 and 0024, predict their second halves", sc)

    report.append(f"({time.perf_counter() - t0:.0f} s)")
    text = "\n".join(report) + "\n"
    OUT.write_text(text, encoding="utf-8")
    sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
