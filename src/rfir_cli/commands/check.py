"""`rfir check ARTIFACT...`: validate files against the schema; every file is checked and reported, the exit
code is the worst file's (the highest: 2 unreadable, 3 invalid)."""
from __future__ import annotations

from typing import Annotated, Optional

import typer
from rich.markup import escape

from ..context import console, err_console, run_guarded
from rfir_core.errors import RfirError, SchemaError
from rfir_core.text import plural


def register(app: typer.Typer) -> None:
    app.command("check")(check)


def check(
    ctx: typer.Context,
    artifacts: Annotated[list[str], typer.Argument(metavar="ARTIFACT", help="Artifacts (.h5) to validate.")],
    kind: Annotated[Optional[str], typer.Option("--kind", metavar="KIND", help="Require this artifact kind.")] = None,
) -> None:
    """Validate artifacts: kind, schema version, required datasets, shapes, dtypes, finite values.

    Every file is checked and reported; the exit code is the worst file's (2 unreadable, 3 invalid)."""
    from rfir_core.artifacts import validate_artifact

    def work():
        bad, worst = 0, 0
        for path in artifacts:
            try:
                problems, code = validate_artifact(path, kind), SchemaError.exit_code
            except RfirError as exc:      # missing, unreadable, or not the --kind asked for
                if len(artifacts) == 1:
                    raise
                problems, code = [str(exc)], exc.exit_code
            if problems:
                bad, worst = bad + 1, max(worst, code)
                for problem in problems:
                    err_console.print(f"[red]invalid:[/red] {escape(problem)}", highlight=False, soft_wrap=True)
            else:
                console.print(f"[green]ok[/green] {escape(path)}", highlight=False, soft_wrap=True)
        if bad:
            failed = RfirError(f"{bad} of {plural(len(artifacts), 'artifact')} failed validation")
            failed.exit_code = worst
            raise failed

    run_guarded(ctx, work)
