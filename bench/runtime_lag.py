"""When is the mouth widest at the end of an utterance, against when the voice stops? (issue 20, item 7)

Festival says each sentence at two rates; for the last vowel of each, the lip opening ULO + LLO
(the ground truth table, evaluated every millisecond) peaks at some time after the vowel starts:
reported is that time minus the vowel's end (the voice stopping; > 0 = the mouth still opening
in the silence), with the final pause as Festival labels it (it runs to the end of the WAV) and with
the final pause split after `FINAL_PAUSE_S` (what `animate` and `speak` do).

Run: .venv/bin/python bench/runtime_lag.py [--out bench/results/runtime_lag.txt]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from coartic.io.labels import Segments
from coartic.runtime.animate import FINAL_PAUSE_S, evaluate, split_final_pause, substitute, table_channels
from coartic.runtime.festival import PhoneMap, synthesize
from coartic.table import PAUSE, ParameterTable

ROOT = Path(__file__).resolve().parents[1]
SENTENCES = ("Il babbo mangia la pappa.", "Vieni a casa.", "Che bella giornata.", "Andiamo via.",
             "La mamma mangia la mela.", "Il papà va a Roma.")
VOWELS = set("ieEaOou")


def peak_after_voice(table: ParameterTable, seg: Segments, last: int) -> float:
    t = np.arange(seg.starts[last], seg.ends[-1], 0.001)
    ch = evaluate(table, seg, t, ["ULO", "LLO"])
    return float(t[int(np.argmax(ch["ULO"] + ch["LLO"]))] - seg.ends[last])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--table", default=str(ROOT / "corpus-synthetic" / "ground_truth.json"))
    ap.add_argument("--out", default=str(ROOT / "bench" / "results" / "runtime_lag.txt"))
    args = ap.parse_args()
    table = ParameterTable.load(args.table)
    pmap = PhoneMap.load()
    lines = [f"mouth widest after the voice stops (ms, + = later), last vowel of each sentence; table "
             f"{Path(args.table).name}, Festival pc_diphone; final pause split at {FINAL_PAUSE_S:.2f} s", "",
             f"{'sentence':28s} {'stretch':>7s} {'vowel':>5s} {'final pause s':>13s} {'as labelled':>11s} "
             f"{'split':>6s}"]
    before, after = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for stretch in (1.0, 0.6):
            for k, text in enumerate(SENTENCES):
                utt = synthesize(text, Path(tmp) / f"s{k}.wav", stretch=stretch)
                ends = utt.ends.copy()
                phon = pmap.to_phonemes(utt.phones)
                if phon[-1] == PAUSE and utt.duration > ends[-1]:
                    ends[-1] = utt.duration
                seg, _ = substitute(Segments(tuple(phon), utt.starts, ends), table, table_channels(table),
                                    pmap.fallbacks)
                speech = [i for i, p in enumerate(seg.labels) if p != PAUSE]
                last = speech[-1]
                if seg.labels[last] not in VOWELS and phon[last] not in VOWELS:
                    continue
                split, _ = split_final_pause(seg)
                last_split = [i for i, p in enumerate(split.labels) if p != PAUSE][-1]
                b = 1000 * peak_after_voice(table, seg, last)
                a = 1000 * peak_after_voice(table, split, last_split)
                before.append(b)
                after.append(a)
                lines.append(f"{text:28s} {stretch:7.1f} {phon[last]:>5s} {seg.ends[-1] - seg.starts[-1]:13.3f} "
                             f"{b:11.0f} {a:6.0f}")
    lines += ["", f"median: {np.median(before):.0f} ms as labelled, {np.median(after):.0f} ms split; "
              f"worst: {max(before):.0f} ms, {max(after):.0f} ms"]
    text = "\n".join(lines) + "\n"
    print(text, end="")
    Path(args.out).write_text(text)


if __name__ == "__main__":
    main()
