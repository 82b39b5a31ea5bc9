"""Errors that the CLI turns into one clear line and a non-zero exit code.

Stages raise these (never print); `rfir_cli.main` maps each class to an exit code.
"""
from __future__ import annotations


class RfirError(Exception):
    """Base class: a problem the user can fix. The message is shown as one line."""

    exit_code = 1

    def __init__(self, message: str, *, path: str | None = None):
        self.path = str(path) if path is not None else None
        super().__init__(f"{self.path}: {message}" if self.path else message)


class InputFileError(RfirError):
    """A file that is missing, unreadable, or not what the command expects."""

    exit_code = 2


class SchemaError(InputFileError):
    """An artifact that breaks its schema: wrong kind, version, missing field, bad values."""

    exit_code = 3


class ConfigError(RfirError):
    """A bad configuration file, `--set` key or value, or option."""

    exit_code = 4


class StageError(RfirError):
    """A stage could not produce a trustworthy result (e.g. SfM registered too few images)."""

    exit_code = 5
