"""rfir: radio-frequency inverse rendering from photos and radio measurements."""

__version__ = "0.1.0"
