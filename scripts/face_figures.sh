#!/bin/sh
# The face figures of README.md and docs/FACE.md, every one by `coartic view --screenshot`:
# the synthetic session's ground truth on /# a p a f a t a k a u #/, the face at the target frame
# of /p f a u/ from the front and in profile, and /t k/ cut along the midline (the tongue).
# Run from the repository's root: ./scripts/face_figures.sh  (uses .venv's coartic if there is one)
set -eu
coartic=${COARTIC:-$( [ -x .venv/bin/coartic ] && echo .venv/bin/coartic || echo coartic )}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
printf 'start\tend\tlabel\n0.0\t0.20\t#\n0.20\t0.36\ta\n0.36\t0.46\tp\n0.46\t0.62\ta\n0.62\t0.76\tf\n0.76\t0.92\ta\n0.92\t1.02\tt\n1.02\t1.18\ta\n1.18\t1.28\tk\n1.28\t1.44\ta\n1.44\t1.64\tu\n1.64\t1.84\t#\n' > "$work/visemes.tsv"
"$coartic" animate "$work/visemes.tsv" -t corpus-synthetic/ground_truth.json -o "$work/o" --preview none --gltf > /dev/null
mkdir -p docs/img/face
# target frames (25 fps) of LLO for these labels: p 10, a 14, f 17, t 24, k 31, u 38
for shot in p:10 f:17 a:14 u:38; do
  ph=${shot%%:*}; k=${shot#*:}
  "$coartic" view "$work/o" --frame "$k" --face-only 300 --zoom 1.8 --screenshot "docs/img/face/${ph}_front.png" > /dev/null
  "$coartic" view "$work/o" --frame "$k" --face-only 300 --zoom 1.8 --view profile --screenshot "docs/img/face/${ph}_profile.png" > /dev/null
done
for shot in t:24 k:31 f:17; do
  ph=${shot%%:*}; k=${shot#*:}
  "$coartic" view "$work/o" --frame "$k" --face-only 300 --zoom 2.5 --view profile --section --screenshot "docs/img/face/${ph}_section.png" > /dev/null
done
"$coartic" view "$work/o" --frame 14 --view three-quarter --screenshot docs/img/face_view.png > /dev/null
echo "face figures written to docs/img/face/ and docs/img/face_view.png"
