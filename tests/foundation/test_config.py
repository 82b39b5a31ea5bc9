"""Config resolution: defaults, recipes, files, --set, and clear errors for bad keys and values."""
import copy
from pathlib import Path

import pytest

from rfir_core import config as cfg
from rfir_core.config import parse_override, resolve_config, to_toml
from rfir_core.errors import ConfigError


@pytest.fixture
def config_dir(tmp_path, monkeypatch):
    folder = tmp_path / "configs"
    (folder / "recipes").mkdir(parents=True)
    (folder / "fit.toml").write_text('[fit]\nsteps = 100\nlr = 0.01\nname = "a"\nuse_phase = true\n[fit.lobe]\nmin = 1.0\n')
    (folder / "recipes" / "quick.toml").write_text("[fit]\nsteps = 5\n")
    monkeypatch.setenv("RFIR_CONFIG_DIR", str(folder))
    return folder


def test_defaults_recipe_file_and_set_compose_in_order(config_dir, tmp_path):
    user = tmp_path / "user.toml"
    user.write_text("[fit]\nlr = 0.5\n")
    cfg = resolve_config(user, ["fit.name=b", "fit.lobe.min=2", "fit.use_phase=false"], recipe="quick")
    assert cfg["fit"] == {"steps": 5, "lr": 0.5, "name": "b", "use_phase": False, "lobe": {"min": 2.0}}
    assert "steps = 5" in to_toml(cfg)


def test_int_accepted_for_float_but_not_the_reverse(config_dir):
    assert resolve_config(None, ["fit.lr=1"])["fit"]["lr"] == 1.0
    with pytest.raises(ConfigError, match="'fit.steps' .* must be int"):
        resolve_config(None, ["fit.steps=1.5"])


@pytest.mark.parametrize("override, message", [
    ("fit.stepz=3", "unknown config key 'fit.stepz'"),
    ("nosection.a=1", "unknown config key 'nosection'"),
    ("fit.steps", "expected section.key=value"),
    ("steps=3", "key must look like section.key"),
    ("fit.name=[1", "cannot read value"),
    ("fit.use_phase=maybe", "must be bool"),
])
def test_bad_overrides_name_the_problem(config_dir, override, message):
    with pytest.raises(ConfigError, match=message):
        resolve_config(None, [override])


def test_bad_files_and_recipes(config_dir, tmp_path):
    broken = tmp_path / "broken.toml"
    broken.write_text("[fit\n")
    with pytest.raises(ConfigError, match="not valid TOML"):
        resolve_config(broken)
    with pytest.raises(ConfigError, match="config file not found"):
        resolve_config(tmp_path / "missing.toml")
    with pytest.raises(ConfigError, match="unknown recipe 'nope' \\(known: quick\\)"):
        resolve_config(None, recipe="nope")


def test_bare_words_become_strings():
    assert parse_override("a.b=hello") == {"a": {"b": "hello"}}
    assert parse_override("a.b.c=3") == {"a": {"b": {"c": 3}}}


def test_auto_or_number_keys_take_a_number_and_others_keep_their_type():
    c = resolve_config(None, ["simulate.po.max_facet_edge_m=0.01", "rf_fit.room.max_interactions=3"])
    assert c["simulate"]["po"]["max_facet_edge_m"] == 0.01 and c["rf_fit"]["room"]["max_interactions"] == 3
    assert resolve_config(None, [])["rf_fit"]["room"]["max_interactions"] == "auto"
    with pytest.raises(ConfigError, match="must be str"):
        resolve_config(None, ["rf_fit.antenna=3"])


@pytest.mark.parametrize("override, message", [
    ("fit.steps=-3", "'fit.steps' .* must be 0 or more, got -3"),
    ("fit.lr=0", "'fit.lr' .* must be positive"),
    ("fit.lr=-0.1", "must be 0 or more"),
])
def test_values_outside_their_keys_range_are_refused(config_dir, override, message):
    with pytest.raises(ConfigError, match=message):
        resolve_config(None, [override])


def test_the_shipped_defaults_pass_their_own_range_checks_and_real_keys_are_checked():
    """Every configs/*.toml default lies in its range (resolving them alone raises nothing), and the keys a
    user mistypes most are refused out of range: a negative iteration count, a share above 1."""
    resolve_config()
    for override in ("rf_fit.physical.iterations=-3", "simulate.rssi.test_fraction=1.5",
                     "rf_fit.room.device_gain_prior_db=0", "rf_fit.room.max_interactions=-1"):
        with pytest.raises(ConfigError, match=override.split("=")[0]):
            resolve_config(None, [override])
    assert resolve_config(None, ["calibrate.sfm.num_threads=-1"])["calibrate"]["sfm"]["num_threads"] == -1


def _leaves(table: dict, prefix: str = "") -> list[str]:
    return [k for key, value in table.items()
            for k in (_leaves(value, f"{prefix}{key}.") if isinstance(value, dict) else [f"{prefix}{key}"])]


def test_every_shipped_default_and_recipe_value_passes_the_type_and_range_checks():
    """Each configs/*.toml value and each configs/recipes/*.toml value goes through the checks a user's value gets
    (_merge: the default's type, then _check_range): resolving the defaults alone would check none of them."""
    defaults = cfg.load_defaults()
    assert len(_leaves(defaults)) > 100
    cfg._merge(copy.deepcopy(defaults), defaults, "configs/")
    recipes = sorted((cfg.config_dir() / "recipes").glob("*.toml"))
    assert recipes
    for path in recipes:
        cfg._merge(copy.deepcopy(defaults), cfg._read_toml(path, "recipe"), f"configs/recipes/{path.name}")


def test_the_defaults_come_from_the_package_unless_rfir_config_dir_is_set(tmp_path, monkeypatch):
    monkeypatch.delenv("RFIR_CONFIG_DIR", raising=False)
    assert sorted(p.name for p in cfg.config_dir().glob("*.toml")) == sorted(
        p.name for p in (Path(__file__).resolve().parents[2] / "configs").glob("*.toml"))
    monkeypatch.setenv("RFIR_CONFIG_DIR", str(tmp_path))
    assert cfg.config_dir() == tmp_path
    with pytest.raises(ConfigError, match="no default configs"):
        cfg.load_defaults()
