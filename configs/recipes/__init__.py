"""Named recipes (*.toml) over the defaults, installed as rfir_cli._configs.recipes. No code here."""
