"""Named recipes (*.toml) over the defaults, installed as rfir_core._configs.recipes. No code here."""
