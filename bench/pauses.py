"""Pauses: one pause phoneme against three postures (issue 25 item 2; docs/REAL_DATA.md).

Held-out RMSE of ``[model] pauses = "one"`` (every pause is '#', as before) and ``"postures"``
(the default: the initial pause '#', the final '#end', medial '#mid', short pauses in a closure
joined to it; coartic.pauses), each fitted with the product's own fit job (``coartic.jobs.fit``) and
validated by ``coartic.evaluation.validate`` (as ``coartic fit --validate`` / ``--validate-by``): the
table's and the baselines' RMSE (step = each phoneme's training mean, constant = the training mean)
on the same held-out samples, on all of them and on the speech samples only (every pause left out),
pooled over the splits. Corpora:

- the German EMA with every default (fit/ema_german_defaults.toml: both utterances, a spec that sets
  nothing but the recordings), held out by utterance and in time (each utterance's halves);
- the synthetic session (fit/synthetic.toml; ``coartic corpus synth build/session`` first), its own
  splits: repetition 5 held out and the fast rate from the normal one;
- "english-like": the files tests/python/test_pauses.py writes to reproduce the English EMA's pauses
  (an open-lipped breath before each sentence, closed lips after it; three sentences fitted, LA),
  scored with ``coartic score`` on a fast token whose aligner wrote the first 20 ms of a /p/ closure
  as a pause.

    nice -n 10 .venv/bin/python bench/pauses.py [--corpora german,synthetic] [--channels LLO,JO]

Output: bench/results/pauses.txt (CPU minutes: not part of `make test`).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

from coartic.fit import load_spec  # noqa: E402
from coartic.jobs.fit import fit_job  # noqa: E402
from coartic.fit.data import load_utterances, with_spec_pauses  # noqa: E402
from coartic.evaluation.heldout import pooled  # noqa: E402
from coartic.fit.spec import FitSpec  # noqa: E402
from coartic.evaluation.validate import validate_all  # noqa: E402
from coartic.outputs import atomic_write_text  # noqa: E402

MODES = ("one", "postures")
MODELS = ("table", "step", "constant")


def corpora(which: list[str], channels: tuple[str, ...] | None) -> list[tuple[str, FitSpec, list[str | None]]]:
    """(name, spec, [validate groups]: None for the spec's own splits)."""
    out: list[tuple[str, FitSpec, list[str | None]]] = []
    if "german" in which:
        s = load_spec(ROOT / "fit" / "ema_german_defaults.toml")
        out.append(("German EMA, every default", s.with_options(channels=channels or s.channels),
                    ["utterance", "time"]))
    if "synthetic" in which:
        s = load_spec(ROOT / "fit" / "synthetic.toml")
        out.append(("synthetic session", s.with_options(channels=channels or ("LLO", "JO")), [None]))
    return out


def lines_for(name: str, spec: FitSpec, groups: list[str | None]) -> list[str]:
    out = [f"## {name}: {spec.path.relative_to(ROOT)}, channels {','.join(spec.channels)}",
           f"{'split':10s} {'pauses':9s} {'ch':4s}" + "".join(f"{m + ' all':>14s}{m + ' speech':>15s}" for m in MODELS)
           + f"{'train':>8s}"]
    utts = load_utterances(spec.with_options(pauses="one"))  # as read; each mode gives the pauses their rows
    for group in groups:
        for mode in MODES:
            s = spec.with_options(pauses=mode)
            if group is not None:
                s = s.with_options(validate={"group": group})
            notes: list[str] = []
            scores = validate_all(s, None, utterances=with_spec_pauses(s, utts, notes), quiet=True, notes=notes, fit=fit_job)
            per = {m: (pooled(scores, m), pooled(scores, m, speech=True)) for m in MODELS}
            for ch in spec.channels:
                cells = ""
                for m in MODELS:
                    a, sp = per[m][0].get(ch), per[m][1].get(ch)
                    cells += (f"{a[0]:7.3f}/{a[1]:6.3f}" if a else f"{'-':>14s}")
                    cells += (f" {sp[0]:7.3f}/{sp[1]:6.3f}" if sp else f"{'-':>15s}")
                train = [sc.train_rmse for sc in scores if sc.channel == ch]
                out.append(f"{group or 'spec':10s} {mode:9s} {ch:4s}{cells}{sum(train) / max(len(train), 1):8.3f}")
            out += [f"  note ({group or 'spec'}, {mode}): {n}" for n in notes if not n.startswith("pauses:")]
            print("\n".join(out[-len(spec.channels):]), flush=True)
    return out


def english_like() -> list[str]:
    """The English pauses reproduced (tests/python/test_pauses.py's files): fit three sentences, score
    the fast token with `coartic score`'s function, per mode."""
    import tempfile

    import numpy as np

    sys.path.insert(0, str(ROOT / "tests" / "python"))
    from test_pauses import SENTENCES, spec_for, write_recording

    from coartic.evaluation.score import score_recordings

    tmp = Path(tempfile.mkdtemp(prefix="pauses_"))
    files = [write_recording(tmp, f"s{k}", labels, durs) for k, (labels, durs) in enumerate(SENTENCES)]
    labels, durs = SENTENCES[2]
    ends = np.cumsum(durs)
    starts = np.concatenate([[0.0], ends[:-1]])
    rows = [(float(s), float(e), lab) for s, e, lab in zip(starts, ends, labels)]
    rows[5:6] = [(float(starts[5]), float(starts[5]) + 0.02, "#"), (float(starts[5]) + 0.02, float(ends[5]), "p")]
    held = write_recording(tmp, "fast", labels, durs, rows)
    out = ["## english-like: tests/python/test_pauses.py's files, 3 sentences fitted, the fast token scored (LA)",
           f"{'pauses':9s} {'model':9s}{'all':>16s}{'speech':>16s}{'samples':>9s}"]
    for mode in MODES:
        fit_job(spec_for(tmp, files, mode), tmp / mode, quiet=True, report=False)
        sc = score_recordings(tmp / mode / "table.json", [held[0]], [held[1]], train=tmp / f"spec_{mode}.toml")
        for r in sc.baseline_rows():
            if r["model"] in MODELS:
                out.append(f"{mode:9s} {r['model']:9s}{r['rmse_mm']:8.3f}/{r['rmse_offset_removed_mm']:6.3f}"
                           f" {r['rmse_speech_mm']:8.3f}/{r['rmse_speech_offset_removed_mm']:6.3f}"
                           f"{r['samples']:5d}/{r['speech_samples']}")
        print("\n".join(out[-3:]), flush=True)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--corpora", default="german,synthetic,english-like")
    ap.add_argument("--channels", default=None, help="channels of every corpus (default: German LA,JO; synthetic LLO,JO)")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "pauses.txt")
    a = ap.parse_args()
    t0 = time.perf_counter()
    lines = ["# bench/pauses.py: held-out RMSE (mm), pooled over the splits, as measured/offset removed; 'all' every "
             "held-out sample, 'speech' the samples inside speech segments only (every pause left out)",
             f"# command: nice -n 10 .venv/bin/python bench/pauses.py {' '.join(sys.argv[1:])}".rstrip()]
    chans = tuple(a.channels.split(",")) if a.channels else None
    for name, spec, groups in corpora(a.corpora.split(","), chans):
        lines += lines_for(name, spec, groups) + [""]
        atomic_write_text(a.out, "\n".join(lines) + "\n")
    if "english-like" in a.corpora.split(","):
        lines += english_like() + [""]
    lines.append(f"({time.perf_counter() - t0:.0f} s wall)")
    atomic_write_text(a.out, "\n".join(lines) + "\n")
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
