"""Check command-line overrides before Hydra runs, so a typo gets one line with the closest valid names."""

from __future__ import annotations

import difflib
from pathlib import Path

from omegaconf import OmegaConf

from sfmnet.errors import SfmnetError


def flat_keys(config: dict, prefix: str = "") -> list[str]:
    """Every key path of a plain nested dict, e.g. ``data.errors.friction``."""
    keys = []
    for key, value in config.items():
        path = f"{prefix}{key}"
        keys.append(path)
        if isinstance(value, dict):
            keys.extend(flat_keys(value, f"{path}."))
    return keys


def suggestion(name: str, choices: list[str]) -> str:
    close = difflib.get_close_matches(name, choices, n=1, cutoff=0.6)
    return f" (did you mean '{close[0]}'?)" if close else ""


def check_overrides(overrides: list[str], config_dir: str, sweep: bool = False) -> None:
    """Raise :class:`SfmnetError` naming the first override that selects or sets something that does not exist.

    Group selections (``experiment=fingertp``) are checked against the files in ``conf/<group>/``;
    keys (``data.nosie_fraction=0.1``) against the config they would change. In a sweep (``-m``)
    every value of a swept group is checked, and the keys against the first combination.
    ``hydra.*`` keys and ``+``/``~`` overrides are left to Hydra.
    """
    from hydra import compose, initialize_config_dir

    groups = {path.name: sorted(p.stem for p in path.glob("*.yaml")) for path in Path(config_dir).iterdir() if path.is_dir()}
    selections: list[str] = []
    settings: list[str] = []
    given: set[str] = set()
    for item in overrides:
        key, sep, value = item.partition("=")
        if not sep:
            continue
        given.add(key.lstrip("+"))
        if key.startswith(("hydra.", "+", "~")):
            continue
        if key in groups:
            values = [v.strip() for v in value.split(",")] if sweep else [value]
            for choice in values:
                if choice not in groups[key]:
                    raise SfmnetError(
                        f"unknown {key} '{choice}'{suggestion(choice, groups[key])}: choose one of {', '.join(groups[key])}"
                    )
            selections.append(f"{key}={values[0]}")
        else:
            settings.append(key)
    with initialize_config_dir(config_dir=config_dir, version_base="1.3"):
        config = compose(config_name="train", overrides=selections)
    keys = flat_keys(OmegaConf.to_container(config, resolve=False, throw_on_missing=False))
    for key in settings:
        if key not in keys:
            raise SfmnetError(
                f"unknown config key '{key}'{suggestion(key, keys)}: see python -m sfmnet train --help "
                "(add a new key with +key=value)"
            )
    missing = sorted(key for key in OmegaConf.missing_keys(config) if key not in given)
    if missing:
        raise SfmnetError(f"{', '.join(missing)} must be given, e.g. {missing[0]}=<value>")
