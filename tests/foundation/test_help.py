"""Every command's --help renders its text as written.

Rich markup once turned the split syntax "sector:A:B" into "sector🅰B" (":A:" is an emoji code) and
would drop anything that looks like a tag ("[m]"). The test walks the whole command tree, so a
command or sub-command added later is covered without touching this file.
"""
import re

import pytest
import typer
from typer.testing import CliRunner

from rfir_cli.main import app

runner = CliRunner()


def _commands() -> list[tuple[list[str], object]]:
    """(argv path, click command) for the app and every command and sub-command under it."""
    out = []

    def walk(cmd, path: list[str]) -> None:
        out.append((path, cmd))
        for name, sub in sorted((getattr(cmd, "commands", None) or {}).items()):   # groups have .commands
            walk(sub, path + [name])

    walk(typer.main.get_command(app), [])
    return out


COMMANDS = _commands()


def _flat(text: str) -> str:
    """Words joined by single spaces, without the borders of rich's help panels."""
    text = re.sub(r"(?<=\w)-\n\s+(?=\w)", "-", text)     # a line broken after a hyphen ("in-\n  process")
    return " ".join(re.sub("[\u2500-\u257f]", " ", text).split())


def test_the_tree_has_the_commands_and_sub_commands():
    paths = {" ".join(p) for p, _ in COMMANDS}
    assert {"", "rf-fit", "import", "import csv", "predict", "predict rssi"} <= paths


@pytest.mark.parametrize("path,cmd", COMMANDS, ids=[" ".join(p) or "rfir" for p, _ in COMMANDS])
def test_help_renders_as_written(path, cmd):
    result = runner.invoke(app, path + ["--help"])
    assert result.exit_code == 0, result.output
    out = result.output
    odd = sorted({c for c in out if ord(c) > 0x2000 and not 0x2500 <= ord(c) <= 0x257F})  # box drawing is fine
    assert not odd, f"unexpected characters {odd} in `rfir {' '.join(path)} --help`"
    flat = _flat(out)
    texts = [p.help for p in cmd.params if getattr(p, "help", None)]
    if cmd.help:
        texts.append(cmd.help.split("\n\n")[0])       # the first paragraph of the docstring
    for text in texts:
        # every word in order, whatever the wrapping: nothing swallowed as markup or emoji
        assert _flat(text.replace("\b", "")) in flat, f"lost text in `rfir {' '.join(path)} --help`: {text!r}"


def test_rf_fit_help_shows_the_split_syntax():
    out = runner.invoke(app, ["rf-fit", "--help"]).output
    assert "sector:A:B" in _flat(out) and "\U0001F170" not in out
    assert re.search(r"range:R", out)
