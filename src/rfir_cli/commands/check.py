"""`rfir check ARTIFACT...`: validate files against the schema; exit non-zero on the first bad one."""
from __future__ import annotations

from typing import Annotated, Optional

import typer

from ..context import console, err_console, run_guarded
from ..errors import SchemaError


def register(app: typer.Typer) -> None:
    app.command("check")(check)


def check(
    ctx: typer.Context,
    artifacts: Annotated[list[str], typer.Argument(help="Artifacts (.h5) to validate.")],
    kind: Annotated[Optional[str], typer.Option("--kind", help="Require this artifact kind.")] = None,
) -> None:
    """Validate artifacts: kind, schema version, required datasets, shapes, dtypes, finite values."""
    from ..artifacts import validate_artifact

    def work():
        bad = 0
        for path in artifacts:
            problems = validate_artifact(path, kind)
            if problems:
                bad += 1
                for problem in problems:
                    err_console.print(f"[red]invalid:[/red] {problem}", highlight=False, soft_wrap=True)
            else:
                console.print(f"[green]ok[/green] {path}", highlight=False)
        if bad:
            raise SchemaError(f"{bad} of {len(artifacts)} artifact(s) failed validation")

    run_guarded(ctx, work)
