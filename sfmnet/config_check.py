"""Check command-line overrides before Hydra runs, so a typo gets one line with the closest valid names.

Overrides are read with Hydra's own parser: a value its grammar cannot take gets the quoted
form that works, a sweep (``a,b``, ``choice(...)``, ``range(...)``, ``glob(...)``) is expanded as
Hydra's sweeper will expand it, and one without ``-m`` is told to add it.
"""

from __future__ import annotations

import difflib
import itertools
from pathlib import Path

from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import InterpolationResolutionError, OmegaConfBaseException

from sfmnet.config_values import check_config
from sfmnet.errors import SfmnetError
from sfmnet.io import check_writable_dir


def flat_keys(config: dict | list, prefix: str = "") -> list[str]:
    """Every key path of plain nested dicts and lists, e.g. ``data.errors.friction``, ``data.configurations.0.mass``."""
    keys = []
    for key, value in config.items() if isinstance(config, dict) else enumerate(config):
        path = f"{prefix}{key}"
        keys.append(path)
        if isinstance(value, (dict, list)):
            keys.extend(flat_keys(value, f"{path}."))
    return keys


def suggestion(name: str, choices: list[str]) -> str:
    close = difflib.get_close_matches(name, choices, n=1, cutoff=0.6)
    return f" (did you mean '{close[0]}'?)" if close else ""


def quoted(item: str) -> str:
    """``key=value`` with the value quoted for Hydra (a list's elements each), and the whole quoted for the shell."""
    key, _, value = item.partition("=")
    if value.startswith("[") and value.endswith("]") and not set("'\"[]") & set(value[1:-1]):
        elements = ",".join(f'"{element.strip()}"' for element in value[1:-1].split(","))
        return f"'{key}=[{elements}]'"
    if '"' in value:
        return f"\"{key}='{value}'\""
    return f"'{key}=\"{value}\"'"


def parse_override(item: str):
    """Hydra's parse of one ``key=value``; a value its grammar cannot take is one line saying how to quote it."""
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import OverrideParseException

    try:
        return OverridesParser.create().parse_overrides([item])[0]
    except OverrideParseException:
        raise SfmnetError(f"Hydra cannot read {item}: {unreadable_value(item)}") from None


def unreadable_value(item: str) -> str:
    """Why Hydra's grammar refused ``key=value`` and what to do: a list or mapping left unfinished (a placeholder, a
    bracket never closed), else the characters that need quotes."""
    value = item.partition("=")[2]
    if value.startswith(("[", "{")):
        if "..." in value:
            return "'...' stands for entries to write out in full (the README's examples use it): give every one"
        for opening, closing in ("[]", "{}"):
            if value.count(opening) != value.count(closing):
                return (
                    f"a '{opening}' is not closed by a '{closing}' (or the reverse): close every bracket, and quote the "
                    "whole setting for the shell"
                )
    return (
        "outside quotes a value may not hold '=', brackets, parentheses, spaces, quotes or non-ASCII letters; "
        f"quote it: {quoted(item)}"
    )


def swept_values(override, item: str, options: list[str]) -> list[str]:
    """The values a ``-m`` run takes for one override, as strings for ``key=value`` (``options``: a group's configs)."""
    from hydra.core.override_parser.types import Glob
    from hydra.errors import HydraException

    value = override.value()
    if isinstance(value, Glob):
        return value.filter(options)
    try:
        return list(override.sweep_string_iterator())
    except HydraException:
        raise SfmnetError(f"{item} is a sweep that -m cannot list: give the values with a,b or choice(...) or range(...)") from None


def check_overrides(overrides: list[str], config_dir: str, sweep: bool = False) -> list[str]:
    """Raise :class:`SfmnetError` naming the first override that Hydra cannot read, that selects or sets something
    that does not exist, or whose value refers to a key that does not exist; or if the run directory cannot be written.

    Group selections (``experiment=fingertp``) are checked against the files in ``conf/<group>/``;
    keys (``data.nosie_fraction=0.1``) against the config they would change. In a sweep (``-m``)
    every value of a swept group is checked, and the rest against the first combination.
    ``hydra.*`` keys and ``+``/``~`` overrides are left to Hydra.

    Returns:
        ``overrides``, where a sweep over groups sets a key that only the swept configs define, with that setting forced
        (``++key=value``): Hydra composes the sweep's own config from the default groups first, and would refuse the key
        there, though every job has it (checked here for every combination of the swept groups).
    """
    from hydra import compose, initialize_config_dir
    from hydra.errors import HydraException

    groups = {path.name: sorted(p.stem for p in path.glob("*.yaml")) for path in Path(config_dir).iterdir() if path.is_dir()}
    selections: list[str] = []
    settings: list[str] = []
    first_job: list[str] = []
    given: set[str] = set()
    emptied: list[str] = []
    swept_groups: dict[str, list[str]] = {}
    plain_settings: dict[str, str] = {}
    deleted: list[str] = []
    for item in overrides:
        if item.startswith("-") or ("=" not in item and not item.startswith("~")):
            continue
        override = parse_override(item)
        key = override.key_or_group
        given.add(key)
        if override.is_sweep_override():
            if not sweep:
                raise SfmnetError(
                    f"{item} gives several values: add -m to run one job per value (a sweep), or, if the commas belong "
                    f"to one value, quote it: {quoted(item)}"
                )
            values = swept_values(override, item, groups.get(key, []))
            if not values:
                raise SfmnetError(f"{item} selects nothing: choose from {', '.join(groups.get(key, []))}")
            first_job.append(f"{override.get_key_element()}={values[0]}")
        else:
            values = [] if override.is_delete() else [override.get_value_element_as_str()]
            first_job.append(item)
        if override.is_delete() and not override.is_hydra_override():
            deleted.append(key)
        if override.is_hydra_override() or override.is_add() or override.is_force_add() or override.is_delete():
            continue
        if key in groups and override.package is None:
            for choice in values:
                if choice not in groups[key]:
                    raise SfmnetError(
                        f"unknown {key} '{choice}'{suggestion(choice, groups[key])}: choose one of {', '.join(groups[key])}"
                    )
            selections.append(f"{key}={values[0]}")
            if override.is_sweep_override():
                swept_groups[key] = values
        elif key not in groups:
            settings.append(key)
            if not override.is_sweep_override():
                plain_settings[key] = item
            if override.value() == {}:
                emptied.append(key)
    with initialize_config_dir(config_dir=config_dir, version_base="1.3"):
        config = compose(config_name="train", overrides=selections)
        keys = flat_keys(OmegaConf.to_container(config, resolve=False, throw_on_missing=False))
        for key in settings:
            # A sweep over groups checks its plain settings against every job's config, below.
            if key not in keys and not (swept_groups and key in plain_settings):
                raise unknown_key(key, keys)
        for key in deleted:
            if OmegaConf.select(config, key, default=MISSING_KEY) is MISSING_KEY:
                parent, _, _ = key.rpartition(".")
                siblings = OmegaConf.select(config, parent) if parent else config
                there = f" ({parent} holds {', '.join(siblings) or 'nothing'})" if isinstance(siblings, DictConfig) else ""
                raise SfmnetError(f"~{key} removes nothing: the config has no {key}{there}")
        for key in emptied:
            kept = OmegaConf.select(config, key)
            # Hydra merges a dict override into the dict it names, so an empty one removes nothing.
            if isinstance(kept, DictConfig) and len(kept):
                raise SfmnetError(
                    f"{key}={{}} removes nothing (Hydra merges it into {key}, which keeps {', '.join(kept)}): drop them "
                    f"all with '~{key}', or one with '~{key}.<name>'"
                )
        missing = sorted(key for key in OmegaConf.missing_keys(config) if key not in given)
        if missing:
            raise SfmnetError(f"{', '.join(missing)} must be given, e.g. {missing[0]}=<value>")
        forced = check_swept_combinations(selections, swept_groups, plain_settings) if swept_groups else set()
        try:
            job = compose(config_name="train", overrides=first_job, return_hydra_config=True)
        except (HydraException, OmegaConfBaseException) as error:
            raise SfmnetError(f"Hydra cannot apply these overrides: {' '.join(str(error).split())}") from None
    task = OmegaConf.masked_copy(job, [key for key in job if key != "hydra"])
    try:
        check_config(task)
    except InterpolationResolutionError:
        # A resolver that needs the running job (${hydra:...}): the run checks it again once Hydra has set it up.
        pass
    output = "hydra.sweep.dir" if sweep else "hydra.run.dir"
    check_writable_dir(Path(OmegaConf.select(job, output)), output)
    return [f"++{item}" if item in forced else item for item in overrides]


MISSING_KEY = object()


def unknown_key(key: str, keys: list[str] | set[str]) -> SfmnetError:
    return SfmnetError(
        f"unknown config key '{key}'{suggestion(key, sorted(keys))}: see python -m sfmnet train --help "
        "(add a new key with +key=value)"
    )


def check_swept_combinations(selections: list[str], swept: dict[str, list[str]], settings: dict[str, str]) -> set[str]:
    """Check the plain ``settings`` (key -> ``key=value``, not swept) against the config of every combination of the
    ``swept`` groups (inside Hydra's ``compose`` context): one line naming a key no job has, or the first jobs that lack
    one. Returns the settings whose key the default groups' config lacks, which Hydra's own compose of the sweep would
    refuse."""
    from hydra import compose

    def keys_of(choices: list[str]) -> set[str]:
        return set(flat_keys(OmegaConf.to_container(compose(config_name="train", overrides=choices), resolve=False)))

    fixed = [choice for choice in selections if choice.partition("=")[0] not in swept]
    jobs = [[f"{group}={value}" for group, value in zip(swept, combination)] for combination in itertools.product(*swept.values())]
    job_keys = [keys_of([*fixed, *choices]) for choices in jobs]
    for key in settings:
        lacking = [choices for choices, keys in zip(jobs, job_keys) if key not in keys]
        if len(lacking) == len(jobs):
            raise unknown_key(key, job_keys[0])
        if lacking:
            raise SfmnetError(
                f"config key '{key}' is not in the jobs with {' '.join(lacking[0])}: sweep over configs that all have it, "
                "or run those jobs apart"
            )
    default_keys = keys_of(fixed)
    return {item for key, item in settings.items() if key not in default_keys}
