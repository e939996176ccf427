#!/usr/bin/env bash
# Everything coartic needs on a fresh Debian machine: system packages (Festival with its Italian
# and English voices, ffmpeg for previews, chromium and checkers for the face's files), a virtual environment
# with the Python dependencies, and the Rust extension built in release mode. Idempotent: a second
# run only rebuilds what changed.
set -euo pipefail
cd "$(dirname "$0")/.."

need_apt=()
command -v festival >/dev/null 2>&1 || need_apt+=(festival)
[ -d /usr/share/festival/voices/italian ] || need_apt+=(festvox-italp16k)
# English voice (kal_diphone, with the CMU lexicon) for `coartic speak --lang en`
[ -d /usr/share/festival/voices/english/kal_diphone ] || need_apt+=(festvox-kallpc16k)
command -v ffmpeg >/dev/null 2>&1 || need_apt+=(ffmpeg)
# coartic align: espeak-ng's library says the transcript with its phone times (German and other languages)
command -v espeak-ng >/dev/null 2>&1 || need_apt+=(espeak-ng)
# the face: viewer test and screenshots (headless Chromium, software WebGL), glTF checks (gltfpack's
# cgltf validator, three.js's GLTFLoader), VRML97 check (tovrmlx3d from view3dscene)
command -v chromium >/dev/null 2>&1 || need_apt+=(chromium)
# coartic perceive's browser tests drive Chromium through Selenium's chromedriver
command -v chromedriver >/dev/null 2>&1 || need_apt+=(chromium-driver)
# and its PostgreSQL test starts a throwaway cluster (initdb, pg_ctl) on a socket of its own
compgen -G "/usr/lib/postgresql/*/bin/initdb" >/dev/null || need_apt+=(postgresql)
command -v gltfpack >/dev/null 2>&1 || need_apt+=(gltfpack)
command -v tovrmlx3d >/dev/null 2>&1 || need_apt+=(view3dscene)
[ -f /usr/share/javascript/three/examples/js/loaders/GLTFLoader.js ] || need_apt+=(libjs-three)
# Blender is not installed here (80 packages); where it is, its glTF importer needs NumPy in the
# system Python that Debian's Blender runs (the Blender tests run only where Blender is)
if command -v blender >/dev/null 2>&1 && ! /usr/bin/python3 -c "import numpy" >/dev/null 2>&1; then
  need_apt+=(python3-numpy)
fi
if ((${#need_apt[@]})); then
  sudo_cmd=""
  [ "$(id -u)" -eq 0 ] || sudo_cmd="sudo"
  echo "setup: installing Debian packages: ${need_apt[*]}"
  $sudo_cmd apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo_cmd apt-get install -y -qq "${need_apt[@]}" >/dev/null
fi

if [ ! -x .venv/bin/python ]; then
  echo "setup: creating .venv"
  python3 -m venv .venv
fi
stamp=.venv/.deps-stamp
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ] || [ constraints.txt -nt "$stamp" ]; then
  echo "setup: installing Python dependencies"
  .venv/bin/pip install -q --upgrade pip
  .venv/bin/pip install -q -c constraints.txt "maturin>=1.7,<2" \
    $(.venv/bin/python - <<'PY'
import tomllib
p = tomllib.load(open("pyproject.toml", "rb"))["project"]
# the core, every extra (the [all] of a pip install) and the test tools; "coartic[...]" entries
# only group the others
extras = [d for group in p["optional-dependencies"].values() for d in group if not d.startswith("coartic[")]
print(" ".join(repr(d)[1:-1] for d in p["dependencies"] + extras))
PY
)
  touch "$stamp"
fi

echo "setup: building the Rust extension (release)"
VIRTUAL_ENV="$PWD/.venv" .venv/bin/maturin develop --release --quiet
# maturin develop leaves coartic importable from python/ via a .pth file; check it really is.
.venv/bin/python -c "import coartic._core" || { echo "setup: the extension did not build" >&2; exit 1; }
