"""The `rfir` command line: global options, then one command per module in rfir_cli.commands."""
from __future__ import annotations

import importlib
from typing import Annotated, Optional

import typer

from . import __version__
from .context import GlobalOptions, run_guarded
from .help_format import RfirGroup

# A command is listed here only once it works end to end.
COMMANDS = ("info", "check", "import_", "import_floorplan", "simulate", "calibrate", "geom", "structure", "mesh_gaussians", "rf_fit", "predict", "predict_rssi",
            "edit", "diagnose")

app = typer.Typer(
    name="rfir",
    help="Radio-frequency inverse rendering: photos + radio measurements -> a Gaussian scene with radio "
         "materials that predicts RCS and RSSI for setups nobody measured.",
    no_args_is_help=True,
    add_completion=False,
    rich_markup_mode=None,   # help as written: rich markup would turn "sector:A:B" into an emoji
    pretty_exceptions_enable=False,
    context_settings={"help_option_names": ["-h", "--help"]},
    cls=RfirGroup,           # click-style help: SCENE, --tx X,Y,Z (help_format.py)
    epilog="\b\nExit codes (errors.py):\n  0    ok\n  1    error\n  2    input file: missing, unreadable or not "
           "what the command expects\n  3    schema: wrong kind, version or field\n  4    configuration or option\n"
           "  5    stage: no trustworthy result\n  70   internal error\n  130  interrupted",
)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"rfir {__version__}")
        raise typer.Exit()


@app.callback()
def main_callback(
    ctx: typer.Context,
    config: Annotated[Optional[str], typer.Option("--config", metavar="FILE",
            help="TOML file overriding configs/ defaults.")] = None,
    set_: Annotated[Optional[list[str]], typer.Option("--set", metavar="SECTION.KEY=VALUE",
            help="Override one key: section.key=value (repeatable).")] = None,
    recipe: Annotated[Optional[str], typer.Option("--recipe", metavar="NAME",
            help="Named recipe from configs/recipes/ (e.g. demo).")] = None,
    device: Annotated[str, typer.Option("--device", metavar="auto|cpu|cuda", help="auto, cpu or cuda.")] = "auto",
    seed: Annotated[int, typer.Option("--seed", metavar="INTEGER", help="Random seed for every stage.")] = 0,
    verbose: Annotated[int, typer.Option("-v", "--verbose", count=True, help="More output; tracebacks on errors.")] = 0,
    quiet: Annotated[bool, typer.Option("-q", "--quiet", help="Only errors and final results.")] = False,
    force: Annotated[bool, typer.Option(
        "--force", help="Let an output replace an existing file of another kind (never an input of the command).")] = False,
    version: Annotated[bool, typer.Option("--version", callback=_version, is_eager=True, help="Show the version.")] = False,
) -> None:
    """Global options apply to every command; put them before the command name."""
    if device not in ("auto", "cpu", "cuda"):
        raise typer.BadParameter(f"{device!r}: expected auto, cpu or cuda", param_hint="--device")
    ctx.obj = GlobalOptions(config_file=config, overrides=list(set_ or []), recipe=recipe, device=device,
                            seed=seed, verbosity=-1 if quiet else verbose, force=force)
    # outputs never replace the command's inputs, nor (without --force) a file of another kind (artifacts.check_output)
    from rfir_core.artifacts import begin_command, end_command

    begin_command(force)
    ctx.call_on_close(end_command)
    # Resolve once now, so a bad --config/--set/--recipe fails before any work starts.
    run_guarded(ctx, ctx.obj.config)


for _name in COMMANDS:
    importlib.import_module(f"rfir_cli.commands.{_name}").register(app)


def main() -> None:
    """Console-script entry point."""
    app()


if __name__ == "__main__":
    main()
