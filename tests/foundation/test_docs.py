"""docs/artifacts.md matches the schema in code (regenerate with `python -m rfir_core.schema_doc`)."""
from pathlib import Path

from rfir_core.schema_doc import BEGIN, END, schema_markdown

DOCS = Path(__file__).resolve().parents[2] / "docs"


def test_artifact_doc_is_generated_from_current_schema():
    text = (DOCS / "artifacts.md").read_text()
    generated = text.split(BEGIN, 1)[1].split(END, 1)[0].strip()
    assert generated == schema_markdown().strip(), "run: python -m rfir_core.schema_doc docs/artifacts.md"


def test_architecture_doc_exists_and_names_every_stage_package():
    text = (DOCS / "architecture.md").read_text()
    stages = Path(__file__).resolve().parents[2] / "stages"
    for package in sorted(p.name for p in stages.iterdir() if (p / "__init__.py").exists()):
        assert f"rfir_stages.{package}" in text, f"docs/architecture.md does not mention rfir_stages.{package}"
