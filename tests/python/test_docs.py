"""What a newcomer reads: every command's --help keeps the spec's [section] names (rich markup
would eat an unescaped one), and every file the docs point at is in the repository."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

from coartic.cli import COMMANDS, app, load_command

ROOT = Path(__file__).resolve().parents[2]
DOCS = sorted((ROOT / "docs").rglob("*.md")) + [ROOT / "README.md"]


def _commands() -> list[tuple[str, object]]:
    out: list[tuple[str, object]] = []
    for name in COMMANDS:
        cmd = load_command(name)
        subs = getattr(cmd, "commands", None)
        out += [(f"{name} {n}", c) for n, c in subs.items()] if subs else [(name, cmd)]
    return out


@pytest.mark.parametrize("command", [name for name, _ in _commands()])
def test_help_keeps_every_bracketed_name(command: str) -> None:
    cmd = dict(_commands())[command]
    texts = [getattr(cmd, "help", None) or ""] + [getattr(p, "help", None) or "" for p in getattr(cmd, "params", [])]
    # "[validate]", "[model] speakers", "\\[fit] starts": written in the help, so shown by it
    wanted = {m.group(1) for t in texts for m in re.finditer(r"\\?\[([^\[\]]+)\]", t)}
    r = CliRunner().invoke(app, [*command.split(), "--help"], env={"COLUMNS": "2000"})
    shown = " ".join(r.output.split())
    assert r.exit_code == 0, r.output
    assert [w for w in sorted(wanted) if f"[{w}]" not in shown] == [], f"{command} --help lost these (escape as \\[)"


def _links(text: str) -> list[str]:
    """Relative paths a page sends the reader to: markdown links, and `path.md` in backticks."""
    out = [m.group(1) for m in re.finditer(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text)]
    out += [m.group(1) for m in re.finditer(r"`((?:\.\./|docs/|\.\./\.\./)[\w./-]+\.md)`", text)]
    return [u for u in out if not re.match(r"[a-z]+:", u)]


@pytest.mark.parametrize("page", DOCS, ids=[str(p.relative_to(ROOT)) for p in DOCS])
def test_every_page_the_docs_point_at_exists(page: Path) -> None:
    missing = []
    for link in _links(page.read_text(encoding="utf-8")):
        here = (page.parent / link).resolve()
        from_root = (ROOT / link).resolve()
        if not (here.exists() or from_root.exists()) or not (here.is_relative_to(ROOT) or from_root.is_relative_to(ROOT)):
            missing.append(link)
    assert missing == [], f"{page.relative_to(ROOT)} points at files not in the repository"


def test_the_binding_specs_are_in_the_repository() -> None:
    first = (ROOT / "docs" / "ARCHITECTURE.md").read_text(encoding="utf-8").split("\n\n")[1]
    assert "shared/spec" not in first
    for name in ("MODEL", "CORPUS", "FORMATS"):
        assert f"spec/{name}.md" in first and (ROOT / "docs" / "spec" / f"{name}.md").is_file()


READER_PAGES = sorted((ROOT / "docs" / "readers").glob("*.md"))


def _examples(page: Path) -> list[tuple[str, list[str]]]:
    """(`coartic inspect ...` line, the lines of the ```text block after its ```sh block)."""
    blocks = re.findall(r"```(sh|text)\n(.*?)```", page.read_text(encoding="utf-8"), flags=re.S)
    out = []
    for (kind, body), (next_kind, shown) in zip(blocks, blocks[1:]):
        if kind == "sh" and next_kind == "text":
            out += [(line.split("#")[0].strip(), [s.strip() for s in shown.splitlines() if s.strip()])
                    for line in body.splitlines() if line.startswith("coartic inspect")]
    return out


@pytest.fixture(scope="module")
def samples(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder laid out as the repository's root after the readers pages' sample commands. Of the
    quick session (`coartic corpus synth build/session --quick`) only the /b/ trials: the pages
    inspect aba_normal_01, the same files as in the whole session (each trial's random stream is its
    own), a seventh of the generation; corpus synth itself is tested in test_synthetic.py."""
    import sys

    from coartic.synthetic_cli import load_generator

    where = tmp_path_factory.mktemp("readers")
    (where / "tests").symlink_to(ROOT / "tests")
    sys.path.insert(0, str(ROOT / "tests" / "python"))
    import format_fixtures

    format_fixtures.write_all(where / "build" / "formats")
    load_generator().generate(where / "build" / "session", quick=True, progress=False, consonants=["b"])
    return where


def test_every_reader_has_a_page_with_an_example() -> None:
    from coartic.io.registry import BUILTIN_READERS

    assert len(BUILTIN_READERS) >= 7
    names = {p.stem for p in READER_PAGES}
    assert {"README", "c3d", "marker-csv", "ema-csv", "emu", "est", "xrmb", "mview", "carstens", "labels"} <= names
    for page in READER_PAGES:
        if page.stem != "README":
            assert _examples(page), f"{page.name} has no `coartic inspect` example with what it prints"


@pytest.mark.parametrize("page", [p for p in READER_PAGES if p.stem != "README"], ids=lambda p: p.stem)
def test_the_reader_pages_commands_print_what_they_show(page: Path, samples: Path,
                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    import shlex

    monkeypatch.chdir(samples)
    for command, shown in _examples(page):
        r = CliRunner().invoke(app, shlex.split(command)[1:], env={"COLUMNS": "300"})
        out = " ".join(r.output.split())
        assert r.exit_code in (0, 1) and "error:" not in out, (command, r.output)
        missing = [s for s in shown if " ".join(s.split()) not in out]
        assert missing == [], (command, r.output)
