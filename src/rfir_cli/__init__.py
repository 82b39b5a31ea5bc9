"""rfir: radio-frequency inverse rendering from photos and radio measurements (the command-line interface)."""

from rfir_core import __version__  # noqa: F401 - one version for the CLI and the core
