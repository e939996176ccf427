"""The fit spec: the shipped specs load, and every mistake is named with the file and key."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from coartic.errors import SpecError
from coartic.estimation.settings import SPEC_KEYS, ModelSettings
from coartic.fit.spec import (ARRAYS, DEFAULT_STAGES, SECTION_KEYS, SECTIONS, CorpusSpec, EngineSection, FitSpec, Override,
                              load_spec)

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("name", ["synthetic.toml", "template.toml", "ema_german.toml", "ema_german_original.toml"])
def test_shipped_specs_load(name: str) -> None:
    s = load_spec(ROOT / "fit" / name)
    assert s.channels and s.engine.name in ("scipy", "nlopt", "casadi")
    assert s.path == ROOT / "fit" / name


def test_synthetic_spec_values() -> None:
    s = load_spec(ROOT / "fit" / "synthetic.toml")
    assert s.corpus.manifest == ROOT / "fit" / ".." / "build" / "session" / "manifest.csv"
    assert s.channels == ("ULO", "LLO", "ULP", "LLP", "LR", "JO")
    assert s.model.reference_phoneme == "a" and s.staging.enabled and s.staging.stages == DEFAULT_STAGES


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "spec.toml"
    p.write_text(text)
    return p


BASE = '[corpus]\nmanifest = "m.csv"\n'


@pytest.mark.parametrize("text, key, words", [
    (BASE + '[engine]\nname = "foo"\n', "engine.name", "unknown engine"),
    (BASE + '[parameters]\nfree = ["target", "tension"]\n', "parameters.free", "tension"),
    (BASE + '[parameters.bounds]\nk_r = [1.0, 0.0]\n', "parameters.bounds.k_r", "below"),
    (BASE + '[parameters.bounds]\ntheta_bw = [0.0, 10.0]\n', "parameters.bounds.theta_bw", "> 0"),
    (BASE + '[model]\nchannels = ["LLO", "XYZ"]\n', "model.channels", "XYZ"),
    (BASE + '[model]\nvariant = "new"\n', "model.variant", "new"),
    (BASE + '[[override]]\nfixed = { k_r = 1.0 }\n', "override #1", "phonemes"),
    (BASE + '[[override]]\nphonemes = ["p"]\nfixed = { kr = 1.0 }\n', "override #1.fixed", "kr"),
    ('colour = "red"\n' + BASE, "top level", "colour"),
    ('[model]\nchannels = ["LLO"]\n', "corpus", "missing"),
    ('[corpus]\nfiles = ["a.c3d", "b.c3d"]\nlabels = ["a.lab"]\n', "corpus.labels", "2 data files"),
    (BASE + '[staging]\nstages = [["target"], ["speed"]]\n', "staging.stages", "speed"),
    # issue 21's hostile specs: each names the file, the key, and the phoneme by name
    (BASE + '[[override]]\nphonemes = ["b"]\nfixed = { theta_bw = -3.0 }\n', "override #1.fixed.theta_bw",
     "theta_bw = -3 (of b) is outside (0, inf), the model's domain"),
    (BASE + '[[override]]\nphonemes = ["p"]\nstart = { k_r = 1.5 }\n', "override #1.start.k_r", "outside [0, 1]"),
    (BASE + '[parameters]\nstart = { alpha = 0.0 }\n', "parameters.start.alpha", "outside (0, inf)"),
    (BASE + '[model]\nbeta = nan\n', "model.beta", "beta = nan is not finite"),
    (BASE + '[model]\nbeta = inf\n', "model.beta", "beta = inf is not finite (β, how steeply"),
    (BASE + '[model]\nbeta = -1.0\n', "model.beta", "beta = -1.0 is outside [0, inf) (β"),
    (BASE + '[model]\napex_fraction = nan\n', "model.apex_fraction", "apex_fraction = nan is not finite"),
    (BASE + '[model]\nedge_extent = 0.0\n', "model.edge_extent", "edge_extent = 0.0 is outside (0, inf)"),
    (BASE + '[model]\nplateau_fraction = 1.5\n', "model.plateau_fraction", "is outside [0, 1] (h, the half-width"),
    (BASE + '[model]\ndominance = "flat"\n', "model.dominance", "dominance = 'flat' is not one of centre, plateau"),
    (BASE + '[model]\nhandover = 1\n', "model.handover", "handover = 1 is not true or false"),
])
def test_errors_name_file_and_key(tmp_path: Path, text: str, key: str, words: str) -> None:
    p = write(tmp_path, text)
    with pytest.raises(SpecError) as e:
        load_spec(p)
    msg = str(e.value)
    assert str(p) in msg and f"[{key}]" in msg and words in msg
    assert e.value.file == p and e.value.key == key  # the place without parsing the message


def test_the_mcmc_table_is_left_to_coartic_mcmc(tmp_path: Path) -> None:
    s = load_spec(write(tmp_path, BASE + '[mcmc]\nscope = "phonemes"\nwalkers = 40\n'))
    assert s.corpus.manifest == tmp_path / "m.csv"


def test_not_toml_and_missing(tmp_path: Path) -> None:
    with pytest.raises(SpecError, match="not valid TOML"):
        load_spec(write(tmp_path, "[corpus\n"))
    with pytest.raises(SpecError, match="no such fit spec"):
        load_spec(tmp_path / "absent.toml")


def test_paths_relative_to_spec_and_overrides(tmp_path: Path) -> None:
    p = write(tmp_path, BASE + '[[override]]\nphonemes = ["p", "b"]\nchannels = ["LLO"]\n'
              'fixed = { k_r = 1.0 }\nbounds = { target = [-5.0, 0.0] }\n')
    s = load_spec(p)
    assert s.corpus.manifest == tmp_path / "m.csv"
    o = s.parameters.overrides[0]
    assert o.applies("p", "LLO") and not o.applies("p", "ULP") and not o.applies("t", "LLO")
    assert o.fixed == {"k_r": 1.0} and o.bounds == {"target": (-5.0, 0.0)}


def test_a_spec_that_is_not_utf8_names_file_line_and_encoding(tmp_path: Path) -> None:
    p = tmp_path / "spec.toml"
    p.write_bytes((BASE + "# caf\u00e9\n").encode("latin-1"))
    with pytest.raises(SpecError) as e:
        load_spec(p)
    assert str(e.value) == (f"{p}: line 3, column 6: byte 0xe9 is not UTF-8; this fit spec must be UTF-8 text, and it "
                            "decodes as cp1252: save it as UTF-8 (e.g. `iconv -f cp1252 -t utf-8`)")
    d = tmp_path / "dir.toml"
    d.mkdir()
    with pytest.raises(SpecError, match="is a directory, not a fit spec"):
        load_spec(d)


def test_an_error_carries_file_section_entry_key_and_phoneme_name(tmp_path: Path) -> None:
    # issue 21's `phoneme 2, parameter theta_bw: value -3 is outside its domain`: now the file, the
    # third [[override]], the key and the phoneme by name, in the message and the attributes
    p = write(tmp_path, BASE + '[[override]]\nphonemes = ["p"]\n[[override]]\nphonemes = ["m"]\n'
              '[[override]]\nphonemes = ["b"]\nfixed = { theta_bw = -3 }\n')
    with pytest.raises(SpecError) as e:
        load_spec(p)
    err = e.value
    assert str(err) == (f"{p}: [override #3.fixed.theta_bw] theta_bw = -3 (of b) is outside (0, inf), "
                        "the model's domain of theta_bw")
    assert (err.file, err.section, err.entry, err.key) == (p, "override", 2, "override #3.fixed.theta_bw")
    assert (err.phoneme, err.parameter, err.value) == ("b", "theta_bw", -3.0)


@pytest.mark.parametrize("text, key, section", [
    (BASE + '[model]\nbeta = nan\n', "model.beta", "model"),
    (BASE + '[parameters]\nprior_noise = nan\n', "parameters.prior_noise", "parameters"),
    (BASE + '[parameters.bounds]\nLLO = { k_r = [nan, 1.0] }\n', "parameters.bounds.LLO.k_r", "parameters"),
    (BASE + '[parameters.prior]\n"p.k_r" = [nan, 0.1]\n', "parameters.prior.p.k_r", "parameters"),
    (BASE + '[[shrink]]\nphonemes = ["p", "b"]\nparameters = ["target"]\nsd = nan\n', "shrink #1.sd", "shrink"),
    (BASE + '[gaps]\nmax_gap = nan\n', "gaps.max_gap", "gaps"),
])
def test_nan_is_refused_everywhere_with_its_key(tmp_path: Path, text: str, key: str, section: str) -> None:
    p = write(tmp_path, text)
    with pytest.raises(SpecError, match="nan") as e:
        load_spec(p)
    assert str(e.value).startswith(f"{p}: [{key}] ")
    assert (e.value.file, e.value.key, e.value.section) == (p, key, section)


def test_every_problem_of_a_spec_is_listed_at_once(tmp_path: Path) -> None:
    p = write(tmp_path, BASE + '[model]\nchannels = ["LLO", "Q"]\nbeta = "x"\n[fit]\nstarts = 0\n')
    with pytest.raises(SpecError) as e:
        load_spec(p)
    assert [k for k, _ in e.value.problems] == ["model.channels", "model.beta", "fit.starts"]
    assert str(e.value).count(f"{p}: [") == 3 and e.value.key == "model.channels"


def test_unknown_keys_are_named_with_what_is_allowed(tmp_path: Path) -> None:
    with pytest.raises(SpecError, match=r"\[override #1\] unknown key\(s\) \['colour'\]; allowed: \['bounds', "
                       r"'channels', 'fixed', 'free', 'phonemes', 'start'\]") as e:
        load_spec(write(tmp_path, BASE + '[[override]]\nphonemes = ["p"]\ncolour = 2\n'))
    assert (e.value.section, e.value.entry) == ("override", 0)
    with pytest.raises(SpecError, match=r"\[shrink #1\] unknown key\(s\) \['log'\]; allowed: .*'scale'"):
        load_spec(write(tmp_path, BASE + '[[shrink]]\nphonemes = ["p", "b"]\nparameters = ["k_r"]\nsd = 1.0\n'
                        'log = true\n'))


def test_with_options_validates_as_loading_does(tmp_path: Path) -> None:
    p = write(tmp_path, BASE)
    s = load_spec(p)
    assert s.with_options(plateau_fraction=0.3, starts=4).model.plateau_fraction == 0.3
    for changes, key in (({"plateau_fraction": 2.0}, "model.plateau_fraction"),
                         ({"beta": float("nan")}, "model.beta"),
                         ({"free": ("target", "speed")}, "parameters.free"),
                         ({"engine": {"name": "foo"}}, "engine.name"),
                         ({"validate": {"folds": 3}}, "validate.folds"),  # needs a group
                         ({"ties": ({"phonemes": ["a", "i"], "parameters": ["alpha"]},)}, "tie #1"),
                         ({"keep": 8, "starts": 4}, "fit.keep")):
        with pytest.raises(SpecError) as e:
            s.with_options(**changes)
        assert e.value.file == p and e.value.key == key, changes
        assert str(e.value).startswith(f"{p}: [{key}] ")
    with pytest.raises(SpecError, match=r"\[override.fixed.theta_bw\] theta_bw = -3 \(of b\)"):
        Override(("b",), fixed={"theta_bw": -3.0})  # a part made in Python is checked too
    with pytest.raises(SpecError, match=r"\[corpus\] give either manifest"):
        dataclasses.replace(s.corpus, manifest=None)


# every setting of the nested schema: (section, field), the estimation settings' parts included
LEAVES = [(section, f.name) for section, cls in SECTIONS.items() if section not in ("corpus", "choose")
          for f in dataclasses.fields(cls)]
OWN = {"name": "name", "channels": "model.channels", "start_table": "parameters.start_table", "corpus": "corpus",
       "choose": "choose", "model": "model", "parameters": "parameters", "priors": "parameters", "groups": "model",
       "engine": "engine", "staging": "staging", "fit": "fit", "gaps": "gaps", "validate": "validate"}


def _expected_key(section: str, field: str) -> str:
    # the estimation settings are written with their own table's keys; the fit's sections key for key
    return SPEC_KEYS[field] if section in ("model", "parameters", "priors", "groups") else f"{section}.{field}"


def test_every_setting_is_written_by_a_key_of_the_document() -> None:
    # so that none escapes the schema's location of its errors, and the parser reaches every one
    for section, field in LEAVES:
        key = _expected_key(section, field)
        head, _, rest = key.partition(".")
        assert (head in SECTION_KEYS and rest in SECTION_KEYS[head]) or (head in ARRAYS and not rest), (section, field)
    assert {f.name for f in dataclasses.fields(FitSpec)} - {"path"} <= set(OWN)


class _Odd:
    """A value no field takes."""


@pytest.mark.parametrize("field", [f.name for f in dataclasses.fields(FitSpec) if f.name != "path"])
def test_a_bad_value_in_any_field_is_a_spec_error_naming_its_key(tmp_path: Path, field: str) -> None:
    # never pydantic's own ValidationError (not a CoarticError) nor a crash: the schema's errors
    # all pass through spec_error, keyed by the spec's names
    s = load_spec(write(tmp_path, BASE))
    with pytest.raises(SpecError) as e:
        s.with_options(**{field: _Odd()})
    assert e.value.file == tmp_path / "spec.toml" and e.value.key == OWN[field]


@pytest.mark.parametrize("section, field", LEAVES)
def test_a_bad_value_in_any_setting_is_a_spec_error_naming_its_key(tmp_path: Path, section: str, field: str) -> None:
    s = load_spec(write(tmp_path, BASE))
    with pytest.raises(SpecError) as e:
        s.with_options(**{section: {field: _Odd()}})
    assert e.value.file == tmp_path / "spec.toml" and e.value.key == _expected_key(section, field)


def test_the_file_of_an_unreadable_spec_is_an_attribute(tmp_path: Path) -> None:
    p = tmp_path / "spec.toml"
    p.write_bytes(b'[corpus]\nmanifest = "caf\xe9.csv"\n')
    with pytest.raises(SpecError) as e:
        load_spec(p)
    assert e.value.file == p and "line 2, column 16" in str(e.value)


@pytest.mark.parametrize("field", [f.name for f in dataclasses.fields(CorpusSpec)])
def test_a_bad_value_in_any_corpus_field_is_a_spec_error(tmp_path: Path, field: str) -> None:
    s = load_spec(write(tmp_path, BASE))
    with pytest.raises(SpecError) as e:
        dataclasses.replace(s.corpus, **{field: _Odd()})
    assert e.value.key is not None and e.value.key.startswith("corpus")


def test_with_options_names_a_field_that_does_not_exist(tmp_path: Path) -> None:
    s = load_spec(write(tmp_path, BASE))
    with pytest.raises(SpecError, match=r"FitSpec has no field\(s\) \['colour'\]"):
        s.with_options(colour="red")


def test_the_spec_holds_the_estimation_settings_and_sections_change_key_by_key(tmp_path: Path) -> None:
    # [model] and [parameters] land in estimation's own classes (no copy of their fields here)
    s = load_spec(write(tmp_path, BASE + '[model]\nbeta = 2.0\noffsets = 0.3\n[parameters]\nprior_noise = 0.5\n'
                        'start_table = "t.json"\n[engine]\nname = "nlopt"\noptions = { polish = "none" }\n'))
    assert isinstance(s.model, ModelSettings) and s.model.beta == 2.0 and s.groups.offsets == 0.3
    assert s.priors.prior_noise == 0.5 and s.start_table == tmp_path / "t.json"
    assert s.estimation_settings().model is s.model and s.estimation_settings().source == s.path
    # a table of changes keeps the section's other keys; a setting by its name finds its section
    t = s.with_options(engine={"name": "scipy"}, starts=3)
    assert (t.engine.name, t.engine.options, t.fit.starts, t.fit.seed) == ("scipy", {"polish": "none"}, 3, 0)
    assert s.with_options(engine=EngineSection()).engine.options == {}  # or the section whole
    again = FitSpec.from_settings(s.estimation_settings(), s.path, s.name, s.corpus, channels=s.channels,
                                  engine={"name": "nlopt", "options": {"polish": "none"}}, start_table=s.start_table)
    assert again == s
