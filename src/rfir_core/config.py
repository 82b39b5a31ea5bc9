"""Configuration: TOML defaults per stage in configs/, a user file, then `--set` overrides.

The defaults are configs/*.toml at the top of the repository, installed inside the package as rfir_core._configs
(pyproject.toml's package-dir), so that a wheel carries them; RFIR_CONFIG_DIR points at another folder instead.

Resolution order (later wins): configs/<stage>.toml defaults, configs/recipes/<name>.toml when a
recipe is named, `--config FILE.toml`, `--set section.key=value`. Keys must exist in the defaults,
so a typo is an error rather than a silently ignored setting. The resolved config is recorded in
every artifact's provenance as TOML text. No eval, no pickle.
"""
from __future__ import annotations

import copy
import os
import tomllib
from importlib import resources
from pathlib import Path

import tomli_w

from .errors import ConfigError


def config_dir() -> Path:
    """The folder of default configs: RFIR_CONFIG_DIR when set, else the package data rfir_core._configs (the
    repository's configs/; an editable install made before that mapping existed reads configs/ beside src/)."""
    override = os.environ.get("RFIR_CONFIG_DIR")
    if override:
        return Path(override)
    try:
        return Path(str(resources.files("rfir_core._configs")))
    except ModuleNotFoundError:
        checkout = Path(__file__).resolve().parents[2] / "configs"
        if checkout.is_dir():
            return checkout
        raise ConfigError("the default configs (package data rfir_core._configs) are not installed: reinstall rfir "
                          "(pip install .), or set RFIR_CONFIG_DIR to a folder of configs/*.toml") from None


def _read_toml(path: Path, what: str) -> dict:
    try:
        with open(path, "rb") as handle:
            return tomllib.load(handle)
    except FileNotFoundError:
        raise ConfigError(f"{what} not found", path=path) from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"not valid TOML: {exc}", path=path) from None


def load_defaults() -> dict:
    """Merge every configs/*.toml (one table per stage) into one dict."""
    merged: dict = {}
    folder = config_dir()
    paths = sorted(folder.glob("*.toml"))
    if not paths:
        raise ConfigError("no default configs (*.toml) in this folder", path=folder)
    for path in paths:
        for section, table in _read_toml(path, "default config").items():
            if section in merged:
                raise ConfigError(f"section [{section}] is defined twice in configs/", path=path)
            merged[section] = table
    return merged


def _merge(base: dict, update: dict, origin: str, prefix: str = "") -> None:
    """Merge `update` into `base` in place, refusing keys the defaults do not have."""
    for key, value in update.items():
        dotted = f"{prefix}{key}"
        if key not in base:
            raise ConfigError(f"unknown config key '{dotted}' in {origin}")
        if isinstance(base[key], dict):
            if not isinstance(value, dict):
                raise ConfigError(f"'{dotted}' in {origin} must be a table")
            _merge(base[key], value, origin, dotted + ".")
        else:
            base[key] = _check_range(base[key], _coerce(base[key], value, dotted, origin), dotted, origin)


# keys whose default is "auto" and whose value may be a number instead
AUTO_OR_NUMBER = frozenset({"rf_fit.room.max_interactions", "simulate.po.max_facet_edge_m",
                            "simulate.po.shadow_refine_m", "simulate.po.sbr_spacing_m"})


def _coerce(default, value, dotted: str, origin: str):
    """Check `value` against the type of the default (ints are accepted where floats are; the keys of
    AUTO_OR_NUMBER take "auto" or a number, which their stage checks)."""
    if dotted in AUTO_OR_NUMBER and isinstance(value, (int, float)) and not isinstance(value, bool):
        return value
    if isinstance(default, bool) or isinstance(value, bool):
        if isinstance(default, bool) and isinstance(value, bool):
            return value
    elif isinstance(default, float) and isinstance(value, (int, float)):
        return float(value)
    elif isinstance(default, list) and isinstance(value, list):
        return value
    elif type(default) is type(value):
        return value
    raise ConfigError(f"'{dotted}' in {origin} must be {type(default).__name__}, got {value!r}")


# numeric keys whose default is not negative but whose value may be (an offset, a phase, "-1: every core",
# a grid margin: negative puts receivers outside the walls)
SIGNED = frozenset({"calibrate.sfm.num_threads", "simulate.measurement.gain_offset_db",
                    "simulate.measurement.leakage_phase_deg", "simulate.measurement.aspect_offset_deg",
                    "simulate.rssi.rx_margin_m"})
# words in a key that make it a share of a whole, in [0, 1]
SHARE_WORDS = ("fraction", "opacity", "share")
# words in a key whose value must be strictly positive (a step size, a prior's width)
POSITIVE_WORDS = ("lr", "prior_db", "max_memory_gb", "huber_db")


def _check_range(default, value, dotted: str, origin: str):
    """Refuse a number outside the range its key implies: the default's sign (a count, a size or a time given
    as 0 or more stays 0 or more, save SIGNED keys), [0, 1] for shares, > 0 for step sizes and widths."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or dotted in SIGNED:
        return value
    name = dotted.rsplit(".", 1)[-1]
    words = name.split("_")
    counted = dotted in AUTO_OR_NUMBER or (isinstance(default, (int, float)) and not isinstance(default, bool)
                                           and default >= 0)
    if counted and value < 0:
        raise ConfigError(f"'{dotted}' in {origin} must be 0 or more, got {value!r}")
    if any(w in words for w in SHARE_WORDS) and not 0 <= value <= 1:
        raise ConfigError(f"'{dotted}' in {origin} is a share and must lie in [0, 1], got {value!r}")
    positive = any(name == w or name.endswith("_" + w) or name.startswith(w + "_") for w in POSITIVE_WORDS)
    if positive and not value > 0:
        raise ConfigError(f"'{dotted}' in {origin} must be positive, got {value!r}")
    return value


def parse_override(text: str) -> dict:
    """Turn 'section.key=value' into a nested dict; the value is read as TOML (bare words as strings)."""
    if "=" not in text:
        raise ConfigError(f"--set {text!r}: expected section.key=value")
    dotted, raw = (part.strip() for part in text.split("=", 1))
    keys = dotted.split(".")
    if len(keys) < 2 or not all(keys):
        raise ConfigError(f"--set {text!r}: key must look like section.key")
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        if not raw or any(c in raw for c in "[]{}\"'=,"):
            raise ConfigError(f"--set {text!r}: cannot read value {raw!r}") from None
        value = raw
    nested: dict = value
    for key in reversed(keys):
        nested = {key: nested}
    return nested


def resolve_config(config_file: str | Path | None = None, overrides: list[str] | tuple = (),
                   recipe: str | None = None) -> dict:
    """The resolved configuration dict (all sections)."""
    config = copy.deepcopy(load_defaults())
    if recipe:
        path = config_dir() / "recipes" / f"{recipe}.toml"
        if not path.exists():
            known = sorted(p.stem for p in (config_dir() / "recipes").glob("*.toml"))
            raise ConfigError(f"unknown recipe {recipe!r} (known: {', '.join(known) or 'none'})")
        _merge(config, _read_toml(path, "recipe"), f"recipe {recipe}")
    if config_file:
        _merge(config, _read_toml(Path(config_file), "config file"), str(config_file))
    for text in overrides:
        _merge(config, parse_override(text), f"--set {text}")
    return config


def to_toml(config: dict) -> str:
    """TOML text of a config (recorded in provenance)."""
    return tomli_w.dumps(config)
