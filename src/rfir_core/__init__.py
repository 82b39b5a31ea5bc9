"""rfir's shared core: errors, artifacts and their schema, configuration, progress, provenance and the physics
layer. Both the CLI (`rfir_cli`) and the stages (`rfir_stages`) import it; it imports neither."""

__version__ = "0.1.0"
