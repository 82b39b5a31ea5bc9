"""docs/reference/cli.md is the CLI's own help: regenerated, it equals the committed page."""
from pathlib import Path

from rfir_cli.reference import reference

PAGE = Path(__file__).resolve().parents[2] / "docs" / "reference" / "cli.md"


def test_the_command_reference_is_what_the_cli_prints():
    assert PAGE.read_text() == reference(), (
        "docs/reference/cli.md is out of date: python -m rfir_cli.reference > docs/reference/cli.md")


def test_the_reference_holds_every_command():
    text = reference()
    for cmd in ("rfir rf-fit", "rfir import csv", "rfir import floorplan", "rfir predict rssi", "rfir mesh-gaussians"):
        assert f"`{cmd}`" in text
    assert "Exit codes" in text and "{scene}" not in text and "<str>" not in text
