"""Which library for the fit spec's schema? (issue 21, item 2) Measured, in one run:

1. parse time of the repository's fit specs (fit/*.toml but the batch spec), document already read:
   the hand parser the spec had until commit b2b2694 (``git show``), the pydantic v2 schema it has
   now (coartic.fit.spec), and a msgspec prototype of the same sections with their types and
   ranges (``Meta``) and the domain check of ``[[override]]`` values (no cross-field checks, so it
   does less than the other two) — each as a ratio to ``tomllib.loads`` of the same text;
2. import time, in fresh interpreters, interleaved: each parser module after what ``coartic fit``
   has loaded anyway by then (typer runs a command through pydantic: ``typer._adapters``), and
   ``coartic --help`` / ``coartic fit --help`` against ``python -c 'import numpy'``;
3. the errors on issue 21's hostile specs: does each name the file, the section, the entry (the
   3rd ``[[override]]``), the key and the phoneme by name, and does one run list every problem?

msgspec is not a coartic dependency: the run uses it when importable (e.g. ``pip install --target
/tmp/msgspec msgspec`` and ``--with /tmp/msgspec``), else reports it as not measured.

Run: .venv/bin/python bench/spec_schema.py [--repeat 200] [--rounds 7] [--with DIR]
     [--out bench/results/spec_schema.txt]
"""

from __future__ import annotations

import argparse
import importlib.util
import math
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "python"))
HAND_PARSER_COMMIT = "b2b2694"  # the last commit with the hand-written parse_spec


def module_from(tmp: Path, name: str, src: str) -> Any:
    """``src`` imported as module ``name`` of its own (from ``tmp``, where fresh interpreters find it too)."""
    path = tmp / f"{name}.py"
    path.write_text(src)
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def hand_parser(tmp: Path) -> Any:
    """coartic/fit/spec.py as of HAND_PARSER_COMMIT."""
    src = subprocess.run(["git", "-C", str(ROOT), "show", f"{HAND_PARSER_COMMIT}:python/coartic/fit/spec.py"],
                         capture_output=True, text=True, check=True).stdout
    return module_from(tmp, "hand_spec", src)


def schema_parser(tmp: Path) -> Any:
    """coartic/fit/spec.py as it is now, loaded the same way (not through coartic.fit's package)."""
    return module_from(tmp, "schema_spec", (ROOT / "python" / "coartic" / "fit" / "spec.py").read_text())


MSGSPEC_PROTOTYPE = '''
from typing import Annotated, Any, Literal, Union
import msgspec
from msgspec import Meta, Struct, field
from coartic.table import domain_problem, PARAMETERS

Fraction = Annotated[float, Meta(ge=0.0, le=1.0)]
Positive = Annotated[float, Meta(gt=0.0)]
Names = Union[str, list[str]]

class Corpus(Struct, forbid_unknown_fields=True):
    manifest: Union[str, None] = None
    files: list[str] = []
    labels: list[str] = []
    file_column: str = "file"
    label_map: Union[str, None] = None
    role_map: Union[dict[str, Any], None] = None
    select: dict[str, Any] = {}
    limit: Union[Annotated[int, Meta(ge=1)], None] = None

class Model(Struct, forbid_unknown_fields=True):
    variant: Literal["original", "modified"] = "modified"
    channels: list[Literal["ULO", "LLO", "ULP", "LLP", "LR", "JO", "LA", "TTH", "TTA", "TBH", "TBA"]] = []
    reference_phoneme: str = "a"
    apex_fraction: Fraction = 0.5
    edge_extent: Positive = 1.0
    beta: Annotated[float, Meta(ge=0.0)] = 1.0
    fit_beta: bool = False
    beta_bounds: Union[list[float], None] = None
    offsets: Union[str, float] = "none"
    dominance: Literal["centre", "plateau"] = "centre"
    plateau_fraction: Fraction = 0.5
    handover: bool = False
    speakers: Literal["none", "offset", "offset_scale", "targets"] = "none"
    speaker_column: str = "speaker"

def _domain(values, phonemes):
    for k, v in values.items():
        if k not in PARAMETERS:
            raise ValueError(f"unknown parameter {k!r}")
        problem = domain_problem(k, v)
        if problem is not None:
            raise ValueError(f"{k} = {v:g} (of {', '.join(phonemes)}) {problem}")

class Override(Struct, forbid_unknown_fields=True):
    phonemes: Names
    channels: Union[list[str], None] = None
    fixed: dict[str, float] = {}
    free: list[str] = []
    start: dict[str, float] = {}
    bounds: dict[str, list[float]] = {}
    def __post_init__(self):
        ph = [self.phonemes] if isinstance(self.phonemes, str) else self.phonemes
        _domain(self.fixed, ph)
        _domain(self.start, ph)

class Tie(Struct, forbid_unknown_fields=True):
    phonemes: Names
    parameters: Names
    channels: Union[list[str], None] = None

class Shrink(Struct, forbid_unknown_fields=True):
    phonemes: Names
    parameters: Names
    sd: Positive
    scale: Literal["natural", "log"] = "natural"
    channels: Union[list[str], None] = None

class Parameters(Struct, forbid_unknown_fields=True):
    free: list[str] = []
    start: dict[str, float] = {}
    start_table: Union[str, None] = None
    bounds: dict[str, Any] = {}
    target_margin: float = 5.0
    prior: dict[str, Any] = {}
    prior_noise: Positive = 1.0
    def __post_init__(self):
        _domain(self.start, ())

class Engine(Struct, forbid_unknown_fields=True):
    name: Literal["scipy", "nlopt", "casadi"] = "scipy"
    options: dict[str, Any] = {}

class Staging(Struct, forbid_unknown_fields=True):
    enabled: bool = True
    stages: Union[list[list[str]], None] = None

class Fit(Struct, forbid_unknown_fields=True):
    starts: Annotated[int, Meta(ge=1)] = 32
    seed: Annotated[int, Meta(ge=0)] = 0
    probe: Annotated[int, Meta(ge=1)] = 10
    keep: Union[Annotated[int, Meta(ge=1)], None] = None
    include_start: bool = True

class Gaps(Struct, forbid_unknown_fields=True):
    max_gap: float = 0.05

class Validate(Struct, forbid_unknown_fields=True):
    holdout_repetition: Union[int, None] = 5
    train_rate: Union[str, None] = "normal"
    test_rate: Union[str, None] = "fast"
    group: Union[Literal["utterance", "sentence", "rate", "speaker", "repetition"], None] = None
    folds: Union[Annotated[int, Meta(ge=2)], None] = None

class Spec(Struct, forbid_unknown_fields=True):
    corpus: Corpus
    name: Union[str, None] = None
    model: Model = field(default_factory=Model)
    parameters: Parameters = field(default_factory=Parameters)
    override: list[Override] = []
    tie: list[Tie] = []
    shrink: list[Shrink] = []
    choose: Union[dict[str, Any], None] = None
    engine: Engine = field(default_factory=Engine)
    staging: Staging = field(default_factory=Staging)
    fit: Fit = field(default_factory=Fit)
    gaps: Gaps = field(default_factory=Gaps)
    validate: Validate = field(default_factory=Validate)
    mcmc: dict[str, Any] = {}

def parse(raw, path):
    try:
        return msgspec.convert(raw, Spec, strict=True)
    except msgspec.ValidationError as e:
        raise ValueError(f"{path}: {e}") from None
'''


def msgspec_parser(tmp: Path) -> Any | None:
    try:
        import msgspec  # noqa: F401
    except ImportError:
        return None
    return module_from(tmp, "msgspec_spec", MSGSPEC_PROTOTYPE)


def specs() -> list[Path]:
    return sorted(p for p in (ROOT / "fit").glob("*.toml") if not p.name.startswith("batch_"))


def per_parse(fn: Callable[[], Any], repeat: int) -> float:
    """Median seconds of one call, over ``repeat`` calls (after one warm-up)."""
    fn()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


# issue 21's hostile specs a schema sees (the others need the corpus: shared code after parsing),
# and the words each error must hold: section, entry, key, phoneme (None: not applicable)
BASE = '[corpus]\nmanifest = "m.csv"\n'
HOSTILE: list[tuple[str, str, dict[str, str | None]]] = [
    ("override #3 fixes theta_bw = -3 of /b/",
     BASE + '[[override]]\nphonemes = ["p"]\n[[override]]\nphonemes = ["m"]\n'
     '[[override]]\nphonemes = ["b"]\nfixed = { theta_bw = -3.0 }\n',
     {"section": "override", "entry": r"#3|\[2\]", "key": "theta_bw", "phoneme": r"\bb\b"}),
    ("beta = nan", BASE + '[model]\nbeta = nan\n', {"section": "model", "entry": None, "key": "beta", "phoneme": None}),
    ("plateau_fraction = 1.5", BASE + '[model]\nplateau_fraction = 1.5\n',
     {"section": "model", "entry": None, "key": "plateau_fraction", "phoneme": None}),
    ("unknown key in override #2", BASE + '[[override]]\nphonemes = ["p"]\n[[override]]\nphonemes = ["m"]\ncolour = 1\n',
     {"section": "override", "entry": r"#2|\[1\]", "key": "colour", "phoneme": None}),
    ("tie of the reference's alpha", BASE + '[[tie]]\nphonemes = ["a", "i"]\nparameters = ["alpha"]\n',
     {"section": "tie", "entry": r"#1|\[0\]", "key": "alpha", "phoneme": r"'a'"}),
    ("shrink #1 sd = nan", BASE + '[[shrink]]\nphonemes = ["p", "b"]\nparameters = ["target"]\nsd = nan\n',
     {"section": "shrink", "entry": r"#1|\[0\]", "key": "sd", "phoneme": None}),
]
MANY = BASE + '[model]\nchannels = ["LLO", "Q"]\nbeta = "x"\n[fit]\nstarts = 0\n'  # three problems


def error_of(parse: Callable[[dict[str, Any], Path], Any], text: str, path: Path) -> str:
    try:
        parse(tomllib.loads(text), path)
    except Exception as e:  # noqa: BLE001 - each parser's own error type
        return str(e)
    return "(accepted)"


def import_seconds(code: str, rounds: int, env: dict[str, str]) -> float:
    """Median seconds of ``code`` in fresh interpreters (measured inside, start-up excluded)."""
    probe = f"import time\n{code.split('|')[0]}\nt0 = time.perf_counter()\n{code.split('|')[1]}\nprint(time.perf_counter() - t0)"
    out = []
    for _ in range(rounds):
        proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, env=env, check=True)
        out.append(float(proc.stdout.strip().splitlines()[-1]))
    return statistics.median(out)


def wall(cmd: list[str], env: dict[str, str]) -> float:
    t0 = time.perf_counter()
    subprocess.run(cmd, capture_output=True, env=env, check=True)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=200)
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--with", dest="extra", default=None, help="a folder to import msgspec from")
    ap.add_argument("--out", default=str(ROOT / "bench" / "results" / "spec_schema.txt"))
    args = ap.parse_args()
    if args.extra:
        sys.path.insert(0, args.extra)
    lines: list[str] = []

    def say(s: str = "") -> None:
        print(s)
        lines.append(s)

    load0 = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as t:
        tmp = Path(t)
        hand = hand_parser(tmp)
        schema = schema_parser(tmp)
        ms = msgspec_parser(tmp)
        parsers: dict[str, Callable[[dict[str, Any], Path], Any]] = {
            f"hand parser ({HAND_PARSER_COMMIT})": hand.parse_spec, "pydantic v2 schema (now)": schema.parse_spec}
        if ms is not None:
            parsers["msgspec prototype"] = ms.parse
        import pydantic

        versions = f"pydantic {pydantic.VERSION}" + (f", msgspec {sys.modules['msgspec'].__version__}" if ms else
                                                     ", msgspec not importable (not measured)")
        say(f"fit spec schema: parse time, import time and errors, one run; {versions}")
        say(f"machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, load average "
            f"{load0:.1f} at the start")
        say()
        say(f"1. parse time of the {len(specs())} fit specs in fit/ (document already read; median of {args.repeat} "
            "parses each, summed), against tomllib.loads of the same text")
        texts = {p: p.read_text(encoding="utf-8") for p in specs()}
        docs = {p: tomllib.loads(s) for p, s in texts.items()}
        ref = sum(per_parse(lambda s=s: tomllib.loads(s), args.repeat) for s in texts.values())
        say(f"{'parser':32s} {'µs total':>10s} {'x tomllib':>10s}")
        say(f"{'tomllib.loads (reference)':32s} {ref * 1e6:10.0f} {1.0:10.2f}")
        for name, parse in parsers.items():
            total = sum(per_parse(lambda p=p, d=d, parse=parse: parse(d, p), args.repeat) for p, d in docs.items())
            say(f"{name:32s} {total * 1e6:10.0f} {total / ref:10.2f}")
        say()

        say(f"2. import time in fresh interpreters (median of {args.rounds}), after what `coartic fit` has loaded "
            "by then (typer runs every command through pydantic)")
        env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT / "python"), str(tmp)]
                                                           + ([args.extra] if args.extra else [])), "COLUMNS": "100"}
        before = "import typer._adapters, coartic.table, coartic.io.roles, coartic.textfile"
        cases = {"pydantic (alone, before anything)": "|import pydantic",
                 "typer._adapters (pydantic included)": "|import typer._adapters",
                 f"hand parser ({HAND_PARSER_COMMIT})": f"{before}|import hand_spec",
                 "pydantic v2 schema (now)": f"{before}|import schema_spec"}
        if ms is not None:
            cases["msgspec prototype"] = f"{before}|import msgspec_spec"
            cases["msgspec (alone)"] = "|import msgspec"
        for name, code in cases.items():
            say(f"{name:42s} {import_seconds(code, args.rounds, env) * 1e3:8.1f} ms")
        py = sys.executable
        cmds = {"python -c 'import numpy'": [py, "-c", "import numpy"],
                "coartic --help": [py, "-m", "coartic.cli", "--help"],
                "coartic fit --help": [py, "-m", "coartic.cli", "fit", "--help"]}
        walls: dict[str, list[float]] = {k: [] for k in cmds}
        for _ in range(args.rounds):  # interleaved: each sees the same load
            for k, c in cmds.items():
                walls[k].append(wall(c, env))
        base = statistics.median(walls["python -c 'import numpy'"])
        for k, w in walls.items():
            say(f"{k:42s} {statistics.median(w):8.3f} s {statistics.median(w) / base:6.2f} x numpy")
        probe = subprocess.run([py, "-c", "import sys\nfrom coartic.cli import app\ntry:\n    app(['--help'], "
                                "standalone_mode=False)\nexcept BaseException:\n    pass\nprint('pydantic' in sys.modules)"],
                               capture_output=True, text=True, env=env, check=True).stdout.split()[-1]
        say(f"`coartic --help` imports pydantic: {probe}")
        say()

        say("3. errors on issue 21's hostile specs: does the message name the file, section, entry, key, phoneme?")
        path = tmp / "spec.toml"
        import re

        header = f"{'case':40s} {'parser':32s} file sect entry key  phon"
        say(header)
        for case, text, want in HOSTILE:
            for name, parse in parsers.items():
                msg = error_of(parse, text, path)
                marks = ["yes " if str(path) in msg else "no  "]
                for what in ("section", "entry", "key", "phoneme"):
                    w = want[what]
                    marks.append("-   " if w is None else ("yes " if re.search(w, msg) else "no  "))
                say(f"{case:40s} {name:32s} {' '.join(marks)}")
        say()
        say("   the messages:")
        for case, text, _ in HOSTILE:
            for name, parse in parsers.items():
                say(f"   [{name}] {case}: {error_of(parse, text, path).replace(str(tmp), '<tmp>')}")
        say()
        say("   a spec with three problems (unknown channel, beta = \"x\", starts = 0): problems named in one run")
        for name, parse in parsers.items():
            msg = error_of(parse, MANY, path)
            named = sum(bool(re.search(k, msg)) for k in (r"'Q'|\bQ\b", r"beta", r"starts"))
            say(f"   {name:32s} {named} of 3: {msg.splitlines()[0].replace(str(tmp), '<tmp>')[:150]}")

        say()
        say("4. a spec changed in Python (with_options / dataclasses.replace; msgspec.structs.replace): is the change "
            "checked? (plateau_fraction = 2.0, outside [0, 1])")
        base = tomllib.loads(BASE)
        checks: dict[str, Callable[[], Any]] = {
            f"hand parser ({HAND_PARSER_COMMIT})": lambda: hand.parse_spec(base, path).with_options(plateau_fraction=2.0),
            "pydantic v2 schema (now)": lambda: schema.parse_spec(base, path).with_options(plateau_fraction=2.0)}
        if ms is not None:
            import msgspec

            checks["msgspec prototype"] = lambda: msgspec.structs.replace(
                ms.parse(base, path), model=msgspec.structs.replace(ms.parse(base, path).model, plateau_fraction=2.0))
        for name, change in checks.items():
            try:
                change()
                verdict = "accepted: the spec now holds a value loading refuses"
            except Exception as e:  # noqa: BLE001
                verdict = f"refused: {str(e).replace(str(tmp), '<tmp>')[:120]}"
            say(f"   {name:32s} {verdict}")
    say()
    say(f"load average {os.getloadavg()[0]:.1f} at the end")
    Path(args.out).write_text("\n".join(lines) + "\n", encoding="utf-8")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
