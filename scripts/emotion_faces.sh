#!/bin/sh
# The emotion figures of docs/EMOTIONS.md, every one by `coartic view --screenshot`: the emotive
# flavour's ground-truth table (neutral lip targets of corpus-synthetic/ground_truth.json with each
# emotion's deviations, corpus-synthetic/emotions.toml) on /# a b a v a #/, spoken neutrally and with each
# of the six emotions at intensity 1 (`coartic animate --emotion E --gltf`), the face from the front at
# the target frame of the first /a/ (frame 30 at 25 fps: 1 s of pause first).
# Run from the repository's root: ./scripts/emotion_faces.sh  (uses .venv's python if there is one)
set -eu
py=${PYTHON:-$( [ -x .venv/bin/python ] && echo .venv/bin/python || echo python3 )}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
"$py" -c "
import sys
from coartic.synthetic_cli import load_generator
from coartic.table import ParameterTable
g = load_generator()
g.emotive_truth(ParameterTable.load('corpus-synthetic/ground_truth.json'), g.load_emotions()).save(sys.argv[1])
" "$work/emotive.json"
printf 'start\tend\tlabel\n0.0\t1.00\t#\n1.00\t1.40\ta\n1.40\t1.50\tb\n1.50\t1.66\ta\n1.66\t1.78\tv\n1.78\t1.94\ta\n1.94\t2.30\t#\n' > "$work/abava.tsv"
mkdir -p docs/img/emotion
for e in neutral joy surprise sadness disgust anger fear; do
  if [ "$e" = neutral ]; then extra=""; else extra="--emotion $e"; fi
  # shellcheck disable=SC2086
  "$py" -m coartic.cli animate "$work/abava.tsv" --table "$work/emotive.json" $extra -o "$work/$e" --preview none --gltf > /dev/null
  "$py" -m coartic.cli view "$work/$e" --frame 30 --face-only 260 --zoom 1.15 --screenshot "docs/img/emotion/$e.png" > /dev/null
done
echo "emotion figures written to docs/img/emotion/"
