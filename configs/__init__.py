"""The stage defaults (*.toml), installed as the package data rfir_cli._configs (pyproject.toml's package-dir);
rfir_cli.config reads them through importlib.resources. No code here."""
