"""What the face and rig tests share: the synthetic ground-truth table, Debian's three.js (r111,
the one the viewer and the glTF checks load) and one utterance that shows every kind of mouth."""

from __future__ import annotations

from pathlib import Path

GROUND_TRUTH = Path(__file__).resolve().parents[2] / "corpus-synthetic" / "ground_truth.json"
THREE = Path("/usr/share/javascript/three")
# "# a p a f u l a #": a closure, a labiodental, a rounded vowel, a lateral, an open vowel (and a
# blink: the face's first is at 0.6 s)
APAFULA = """0.00 0.30 #
0.30 0.45 a
0.45 0.55 p
0.55 0.70 a
0.70 0.82 f
0.82 0.98 u
0.98 1.06 l
1.06 1.24 a
1.24 1.60 #
"""
