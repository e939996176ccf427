#!/bin/sh
# The face figures of README.md and docs/FACE.md, every one by `coartic view --screenshot`:
# the shipped Italian table (no --table) on /# a p a f a t a k a u #/ (1 s of pause first), the face at the target frame
# of /p f a u/ from the front and in profile, and /t k/ cut along the midline (the tongue).
# Run from the repository's root: ./scripts/face_figures.sh  (uses .venv's coartic if there is one)
set -eu
coartic=${COARTIC:-$( [ -x .venv/bin/coartic ] && echo .venv/bin/coartic || echo coartic )}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
printf 'start\tend\tlabel\n0.0\t1.00\t#\n1.00\t1.16\ta\n1.16\t1.26\tp\n1.26\t1.42\ta\n1.42\t1.56\tf\n1.56\t1.72\ta\n1.72\t1.82\tt\n1.82\t1.98\ta\n1.98\t2.08\tk\n2.08\t2.24\ta\n2.24\t2.44\tu\n2.44\t2.64\t#\n' > "$work/visemes.tsv"
"$coartic" animate "$work/visemes.tsv" -o "$work/o" --preview none --gltf > /dev/null
mkdir -p docs/img/face
# target frames (25 fps) of LLO for these labels: p 30, a 34, f 37, t 44, k 51, u 58 (the first
# blink, 0.6-0.88 s, falls in the pause before them)
for shot in p:30 f:37 a:34 u:58; do
  ph=${shot%%:*}; k=${shot#*:}
  "$coartic" view "$work/o" --frame "$k" --face-only 300 --zoom 1.8 --screenshot "docs/img/face/${ph}_front.png" > /dev/null
  "$coartic" view "$work/o" --frame "$k" --face-only 300 --zoom 1.8 --view profile --screenshot "docs/img/face/${ph}_profile.png" > /dev/null
done
for shot in t:44 k:51 f:37; do
  ph=${shot%%:*}; k=${shot#*:}
  "$coartic" view "$work/o" --frame "$k" --face-only 300 --zoom 2.5 --view profile --section --screenshot "docs/img/face/${ph}_section.png" > /dev/null
done
"$coartic" view "$work/o" --frame 34 --view three-quarter --screenshot docs/img/face_view.png > /dev/null
echo "face figures written to docs/img/face/ and docs/img/face_view.png"
