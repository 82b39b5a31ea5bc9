"""Click-style help for every rfir command: `rfir simulate [OPTIONS] SCENE OUT`, `--tx X,Y,Z`.

typer's own help writes an argument as `{scene}` in the usage line and a value as `<str>`, `<path>` or
`<list[str]>` beside an option. `RfirGroup` (the root group, main.py) gives every command and
sub-command under it the help classes below, so a command added later gets the same help without
touching this file. A parameter's `metavar=` (typer.Argument / typer.Option) names its value: an
argument's metavar, else its name in capitals; an option's metavar, else its type (FILE, FLOAT,
INTEGER, TEXT).
"""
from __future__ import annotations

import pathlib
import typing

from typer.core import TyperCommand, TyperGroup

# an option's value when it names no metavar, by its annotation (the item type of a list)
TYPE_WORDS = {str: "TEXT", int: "INTEGER", float: "FLOAT", pathlib.Path: "PATH", bool: "BOOLEAN"}


def value_name(param) -> str:
    """The placeholder of a parameter's value: its metavar, an argument's name in capitals, or the type's word."""
    if getattr(param, "metavar", None):
        return str(param.metavar)
    if param.param_type_name == "argument":
        return str(param.name or "").upper()
    annotation = getattr(getattr(param, "type_descriptor", None), "annotation", str)
    if typing.get_origin(annotation) in (list, tuple) and typing.get_args(annotation):
        annotation = typing.get_args(annotation)[0]
    if typing.get_origin(annotation) is typing.Union:   # Optional[X] -> X
        annotation = next((a for a in typing.get_args(annotation) if a is not type(None)), str)
    return TYPE_WORDS.get(annotation, "TEXT")


def _is_flag(param) -> bool:
    return bool(getattr(param, "is_flag", False) or getattr(param, "count", False))


def usage_piece(param) -> list[str]:
    """An argument's piece of the usage line: NAME, [NAME] when optional, NAME... when repeated."""
    if param.param_type_name != "argument":
        return []
    name = value_name(param) + ("..." if param.nargs != 1 else "")
    return [name if param.required else f"[{name}]"]


def help_record(param, ctx) -> tuple[str, str] | None:
    """(left column, help) of a parameter: 'SCENE' or '-o, --out FILE', with typer's help text and extras."""
    record = param.get_help_record(ctx)
    if record is None:
        return None
    if param.param_type_name == "argument":
        return value_name(param) + ("..." if param.nargs != 1 else ""), record[1]
    names = ", ".join(sorted(param.opts, key=lambda o: o.startswith("--")))   # -h before --help
    if param.secondary_opts:
        names += " / " + ", ".join(param.secondary_opts)
    if not _is_flag(param):
        names += " " + value_name(param)
    return names, record[1]


def _format_parameters(command, ctx, formatter) -> None:
    args, opts = [], []
    for param in command.get_params(ctx):
        record = help_record(param, ctx)
        if record is not None:
            (args if param.param_type_name == "argument" else opts).append(record)
    if args:
        with formatter.section("Arguments"):
            formatter.write_dl(args)
    if opts:
        with formatter.section("Options"):
            formatter.write_dl(opts)


def _usage_pieces(command, ctx) -> list[str]:
    out = [command.options_metavar] if command.options_metavar else []
    for param in command.get_params(ctx):
        out += usage_piece(param)
    return out


class RfirCommand(TyperCommand):
    """A command whose help is click-style (module docstring)."""

    def collect_usage_pieces(self, ctx) -> list[str]:
        return _usage_pieces(self, ctx)

    def format_options(self, ctx, formatter) -> None:
        _format_parameters(self, ctx, formatter)


class RfirGroup(TyperGroup):
    """A group whose help, and its commands' and sub-groups' help, is click-style (module docstring)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        for command in self.commands.values():
            _adopt(command)

    def collect_usage_pieces(self, ctx) -> list[str]:
        return _usage_pieces(self, ctx) + [self.subcommand_metavar]

    def format_options(self, ctx, formatter) -> None:
        _format_parameters(self, ctx, formatter)
        self.format_commands(ctx, formatter)


def _adopt(command) -> None:
    """Give a typer command or group (and what is under it) the click-style help classes.

    typer builds each command before the root group exists; the classes here only override how help
    is written, so the switch keeps every other behaviour. A command of another class is left as it is."""
    if type(command) is TyperGroup:
        command.__class__ = RfirGroup
    elif type(command) is TyperCommand:
        command.__class__ = RfirCommand
    for param in getattr(command, "params", []):
        if param.param_type_name == "argument" and not param.metavar:
            param.metavar = value_name(param)     # errors name it as help does: "Missing argument 'SCENE'"
    for sub in getattr(command, "commands", {}).values():
        _adopt(sub)
