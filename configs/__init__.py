"""The stage defaults (*.toml), installed as the package data rfir_core._configs (pyproject.toml's package-dir);
rfir_core.config reads them through importlib.resources. No code here."""
