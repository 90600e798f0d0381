"""Config values checked where every run starts (:func:`sfmnet.training.run.train`), one line naming the key.

Two sources say what a value must be:

- the signature of the class a node builds (its ``_target_``, for sfmnet's own classes): a
  ``data.magnitude: float`` given ``abc`` is refused before the data module sees it;
- :data:`RULES`, by dotted key: ranges (``seed >= 0``, ``model.metric_weight > 0``), the keys
  that build nothing (``threads``, ``trainer.max_epochs``) and the structured values
  (``data.mirror_hint``, ``data.configurations``, ``ckpt_path``).
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import inspect
import math
import pickle
import types
import typing
import zipfile
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import GrammarParseError, InterpolationKeyError

from sfmnet.errors import SfmnetError


@dataclass(frozen=True)
class Bound:
    """A number within limits: ``kind`` (``int``: a whole number), ``low``/``high`` (``None``: unbounded),
    open (``>``, ``<``) where ``strict``; ``null`` allowed where ``nullable``; ``why`` follows the remedy."""

    kind: type
    low: float | None = None
    high: float | None = None
    strict: bool = False
    nullable: bool = False
    why: str = ""

    def __call__(self, key: str, value: Any) -> str | None:
        """What is wrong with ``value`` at ``key`` (one line), or None."""
        if value is None and self.nullable:
            return None
        if is_instance(value, self.kind) and math.isfinite(value) and self.within(value):
            return None
        return f"{key} is {value!r}: give {self.requirement()}{f' ({self.why})' if self.why else ''}"

    def within(self, value: float) -> bool:
        above = self.low is None or (value > self.low if self.strict else value >= self.low)
        below = self.high is None or (value < self.high if self.strict else value <= self.high)
        return above and below

    def requirement(self) -> str:
        """E.g. ``a whole number >= 0 and <= 4294967295`` (null, where allowed, goes unsaid)."""
        signs = (">", "<") if self.strict else (">=", "<=")
        limits = [f"{sign} {limit:.15g}" for sign, limit in zip(signs, (self.low, self.high)) if limit is not None]
        return " ".join(["a whole number" if self.kind is int else "a number", " and ".join(limits)]).strip()


def mirror_hint_problem(key: str, value: Any) -> str | None:
    """A file's mirror hint, ``{row: <0-based data row>, axis: <load column>, sign: 1 | -1}``; a simulator's is a bool
    (which of the two a data module takes, its signature says: checked after this)."""
    if value is None or isinstance(value, bool):
        return None
    if (
        isinstance(value, Mapping) and set(value) == {"row", "axis", "sign"} and is_instance(value["row"], int)
        and value["row"] >= 0 and isinstance(value["axis"], str) and is_instance(value["sign"], float) and value["sign"] in (1, -1)
    ):
        return None
    return (
        f"{key} is {value!r}: give null or {{row: <0-based data row>, axis: <load column>, sign: 1 or -1}} "
        "(a simulator's: true or false)"
    )


def configurations_problem(key: str, value: Any) -> str | None:
    """Six-axis mass configurations: a list, or a mapping by id, of ``{mass: kg > 0, centre_of_mass: [x, y, z] m}``."""
    if value is None:
        return None
    entries = list(value.items() if isinstance(value, Mapping) else enumerate(value) if isinstance(value, list) else [])
    if not entries:
        return f"{key} is {value!r}: give one {{mass: <kg>, centre_of_mass: [x, y, z]}} per mass configuration"
    for name, entry in entries:
        if not (
            isinstance(entry, Mapping) and set(entry) == {"mass", "centre_of_mass"}
            and Bound(float, low=0, strict=True)(key, entry["mass"]) is None
            and isinstance(entry["centre_of_mass"], list) and len(entry["centre_of_mass"]) == 3
            and all(Bound(float)(key, x) is None for x in entry["centre_of_mass"])
        ):
            return f"{key}[{name}] is {entry!r}: give {{mass: <kg, > 0>, centre_of_mass: [x, y, z] (m, numbers)}}"
    return None


LIGHTNING_CHECKPOINT_KEYS = ("state_dict", "epoch", "pytorch-lightning_version")


def checkpoint_problem(key: str, value: Any) -> str | None:
    """``ckpt_path``: null, or a Lightning checkpoint file that loads (read here, before any fit starts)."""
    if value is None:
        return None
    remedy = "give a run's checkpoints/<method>/last.ckpt"
    if not isinstance(value, str) or not Path(value).is_file():
        return f"{key} {value} is not a file: {remedy}"
    if not zipfile.is_zipfile(value):
        return (
            f"{key} {value} is not a checkpoint (not the zip archive torch.save writes: truncated, or another kind of "
            f"file): {remedy}"
        )
    import torch

    try:
        checkpoint = torch.load(value, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError:
        return f"{key} {value} is not a Lightning checkpoint (it holds pickled objects, not only tensors and numbers): {remedy}"
    except Exception as error:  # a damaged archive raises its own type
        reason = " ".join(str(error).split())[:200] or type(error).__name__
        return f"{key} {value} cannot be read as a checkpoint ({reason}): {remedy}"
    missing = [name for name in LIGHTNING_CHECKPOINT_KEYS if not isinstance(checkpoint, dict) or name not in checkpoint]
    if missing:
        return f"{key} {value} is not a Lightning checkpoint (it lacks {', '.join(missing)}): {remedy}"
    return None


# What is wrong with a value at a key (one line), or None.
Rule = Callable[[str, Any], str | None]

# What a key must hold, wherever it is set (a key a config does not have is skipped).
RULES: dict[str, Rule] = {
    "seed": Bound(int, low=0, high=2**32 - 1),
    "threads": lambda key, value: None if value == "auto" else Bound(int, low=1, why="or auto")(key, value),
    "ckpt_path": checkpoint_problem,
    # 0 reported an untrained autoencoder's scores as a result (a hostile tester's, exit 0).
    "trainer.max_epochs": Bound(
        int, low=1, nullable=True,
        why="0 trains nothing and -1, Lightning's no limit, never ends a fit; experiment=calibrate_stream skips its "
        "refinement with model.refinement=closed_form",
    ),
    "optimizer.lr": Bound(float, low=0, strict=True),
    "eval.smoothing_window": Bound(int, low=1),
    "eval.closed_loop.runs_per_room": Bound(int, low=1),
    "eval.closed_loop.seconds": Bound(float, low=0, strict=True),
    "eval.closed_loop.escape_seconds": Bound(float, low=0, strict=True),
    "eval.closed_loop.free_seconds": Bound(float, low=0, strict=True),
    "eval.closed_loop.stall_seconds": Bound(float, low=0, strict=True),
    "eval.closed_loop.random_hold_seconds": Bound(float, low=0, strict=True),
    "data.magnitude": Bound(float, low=0, strict=True, nullable=True),
    "data.mass": Bound(float, low=0, strict=True, nullable=True),
    "data.gravity": Bound(float, low=0, strict=True),
    "data.known_load_tolerance": Bound(float, low=0),
    "data.mirror_hint": mirror_hint_problem,
    "data.configurations": configurations_problem,
    "data.samples": Bound(int, low=1),
    "data.channels": Bound(int, low=1),
    "data.known_loads": Bound(int, low=0),
    "data.known_per_configuration": Bound(int, low=0),
    "data.motion_span": Bound(int, low=1, nullable=True),
    "data.poses": Bound(int, low=1),
    "data.repeats": Bound(int, low=1),
    "data.samples_per_turn": Bound(int, low=1),
    "data.test_samples": Bound(int, low=1),
    "data.noise_fraction": Bound(float, low=0),
    "data.noise_std": Bound(float, low=0),
    "data.offset_scale": Bound(float, low=0),
    "data.batch_size": Bound(int, low=1, nullable=True),
    "data.block_rows": Bound(int, low=1, nullable=True),
    "data.test_fraction": Bound(float, low=0, high=1, strict=True),
    "data.train_rooms": Bound(int, low=1),
    "data.test_rooms": Bound(int, low=1),
    "data.episodes_per_room": Bound(int, low=1),
    "data.steps": Bound(int, low=2),
    "data.obstacles": Bound(int, low=0),
    "data.static.window": Bound(float, low=0, strict=True, nullable=True),
    "data.static.min_duration": Bound(float, low=0, strict=True, nullable=True),
    "data.static.threshold": Bound(float, low=0, strict=True, nullable=True),
    "data.static.noise_quantile": Bound(float, low=0, high=1, strict=True, nullable=True),
    "model.rank": Bound(int, low=1, nullable=True),
    "model.metric_weight": Bound(
        float, low=0, strict=True,
        why="0 drops the metric constraint, leaving the calibration right only up to an affine map; the default is 1000",
    ),
    "model.alternation_steps": Bound(int, low=1),
    "model.weight_decay": Bound(float, low=0, why="a negative decay pushes the weights apart"),
}


def check_config(cfg: DictConfig) -> None:
    """Raise :class:`SfmnetError` for the first value that is missing, refers to a key that does not exist, is of the
    wrong type or out of range. (A resolver that fails for another reason raises its own error.)"""
    try:
        missing = sorted(OmegaConf.missing_keys(cfg))
        if missing:
            raise SfmnetError(f"{', '.join(missing)} must be given, e.g. {missing[0]}=<value>")
        values = OmegaConf.to_container(cfg, resolve=True)
    except (InterpolationKeyError, GrammarParseError) as error:
        raise SfmnetError(
            f"{error.full_key} refers to something that does not exist ({str(error.msg).splitlines()[0]}): '${{' starts a "
            "reference to another config key, even inside quotes; a file whose name holds '${' must be renamed or linked "
            "(ln -s) first"
        ) from None
    escaped = next(((key, value) for key, value in strings(values) if "${" in value), None)
    if escaped:
        raise SfmnetError(
            f"{escaped[0]} is {escaped[1]!r}: Hydra reads '${{' as a reference to another key again when it builds the run, "
            "even escaped; rename the file or link to it (ln -s) under a name without '${'"
        )
    for key, rule in RULES.items():
        found, value = lookup(values, key)
        if found:
            problem = rule(key, value)
            if problem:
                raise SfmnetError(problem)
    for key, node, target in target_nodes(values):
        check_arguments(key, node, target)
    check_data_dir(cfg)


def check_data_dir(cfg: DictConfig) -> None:
    """Where ``data.path`` lies in ``paths.data_dir`` (the real recordings of the built-in experiments) and that folder
    is missing, one line saying how to point at it: run from elsewhere, a new user's ``../shared/data`` had been
    "not a folder ...: check data.path", with nothing of ``SFMNET_DATA_DIR``."""
    data = cfg.get("data")
    raw = OmegaConf.to_container(data, resolve=False).get("path") if isinstance(data, DictConfig) else None
    if not (isinstance(raw, str) and "${paths.data_dir}" in raw):
        return
    folder = Path(cfg.paths.data_dir).expanduser()
    if not folder.is_dir():
        where = "" if folder.is_absolute() else f", relative to {Path.cwd()}, the folder you run in"
        raise SfmnetError(
            f"the real recordings' folder {folder} (paths.data_dir{where}) does not exist: set SFMNET_DATA_DIR to the "
            "folder holding ft_printed_sensor/, wall_following/ and imu_xsens/ (an absolute path runs from anywhere), or "
            "give paths.data_dir=<folder>"
        )


def strings(values: Any, prefix: str = "") -> list[tuple[str, str]]:
    """Every text value of plain nested dicts and lists, with its dotted key."""
    if isinstance(values, str):
        return [(prefix.rstrip("."), values)]
    items = values.items() if isinstance(values, dict) else enumerate(values) if isinstance(values, list) else []
    return [found for key, value in items for found in strings(value, f"{prefix}{key}.")]


def lookup(values: Any, key: str) -> tuple[bool, Any]:
    """``(True, value)`` at the dotted ``key`` of plain nested dicts, ``(False, None)`` where a part is absent."""
    for part in key.split("."):
        if not isinstance(values, dict) or part not in values:
            return False, None
        values = values[part]
    return True, values


def target_nodes(values: Any, prefix: str = "") -> list[tuple[str, dict, Callable]]:
    """Every node that builds one of sfmnet's classes or functions: ``(dotted key, node, target)``."""
    from hydra.utils import get_object

    found = []
    if isinstance(values, dict):
        target = values.get("_target_")
        if isinstance(target, str) and target.startswith("sfmnet."):
            found.append((prefix.rstrip("."), values, get_object(target)))
        for key, value in values.items():
            found.extend(target_nodes(value, f"{prefix}{key}."))
    return found


def check_arguments(key: str, node: dict, target: Callable) -> None:
    """Each value of ``node`` against the annotation of the parameter it is passed to; a value no parameter takes
    (``+data.foo=1``) is refused."""
    hints = parameter_hints(target)
    for name, value in node.items():
        if name.startswith("_"):
            continue
        if name not in hints:
            if name not in parameter_names(target):
                close = difflib.get_close_matches(name, sorted(hints), n=1, cutoff=0.6)
                raise SfmnetError(
                    f"{key}.{name} is not a setting of {key} ({node['_target_']})"
                    + (f": did you mean {key}.{close[0]}?" if close else f": its settings are {', '.join(sorted(hints))}")
                )
            continue
        problem = type_problem(value, hints[name], f"{key}.{name}")
        if problem:
            raise SfmnetError(problem)


@functools.cache
def parameter_names(target: Callable) -> set[str]:
    """Every parameter name ``target`` (a class: any ``__init__`` of its bases) takes, annotated or not."""
    functions = [klass.__init__ for klass in target.__mro__ if "__init__" in vars(klass)] if isinstance(target, type) else [target]
    names: set[str] = set()
    for function in functions:
        try:
            names.update(inspect.signature(function).parameters)
        except (TypeError, ValueError):
            continue
    return names


@functools.cache
def parameter_hints(target: Callable) -> dict[str, Any]:
    """The annotated parameters of ``target``; a class's include those its ``**kwargs`` pass to its bases."""
    if not isinstance(target, type):
        return typing.get_type_hints(target)
    hints: dict[str, Any] = {}
    for klass in reversed(target.__mro__):
        if "__init__" in vars(klass) and klass.__module__.startswith("sfmnet."):
            hints.update(typing.get_type_hints(klass.__init__))
    hints.pop("return", None)
    return hints


def type_problem(value: Any, hint: Any, key: str) -> str | None:
    """Why ``value`` does not fit ``hint`` (one line naming ``key``), or None; a dataclass's fields are checked too."""
    if not matches(value, hint):
        return f"{key} is {value!r}: give {describe(hint)}"
    fields = next((h for h in alternatives(hint) if dataclasses.is_dataclass(h)), None)
    if fields is not None and isinstance(value, dict):
        field_hints = typing.get_type_hints(fields)
        for name, item in value.items():
            if name in field_hints:
                problem = type_problem(item, field_hints[name], f"{key}.{name}")
                if problem:
                    return problem
    return None


def alternatives(hint: Any) -> tuple[Any, ...]:
    """The members of a union (``X | Y``, ``Optional[X]``), else ``(hint,)``."""
    return typing.get_args(hint) if typing.get_origin(hint) in (typing.Union, types.UnionType) else (hint,)


def is_instance(value: Any, kind: type) -> bool:
    """``isinstance`` as a config means it: a bool is not a number, and a whole number is a float."""
    if isinstance(value, bool):
        return kind is bool
    if kind is float:
        return isinstance(value, (int, float))
    return isinstance(value, kind)


def matches(value: Any, hint: Any) -> bool:
    """Whether a plain config value (None, bool, number, str, list, dict) can be passed where ``hint`` is declared."""
    if hint is Any:
        return True
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        return any(matches(value, option) for option in typing.get_args(hint))
    if hint is None or hint is type(None):
        return value is None
    origin, arguments = typing.get_origin(hint) or hint, typing.get_args(hint)
    if origin in (list, tuple, set, frozenset, Sequence):
        if not isinstance(value, list):
            return False
        if origin is tuple and arguments and arguments[-1] is not Ellipsis:
            return len(value) == len(arguments) and all(matches(v, a) for v, a in zip(value, arguments))
        return not arguments or all(matches(item, arguments[0]) for item in value)
    if origin in (dict, Mapping):
        return isinstance(value, dict) and (not arguments or all(matches(item, arguments[1]) for item in value.values()))
    if origin is typing.Literal:
        return value in arguments
    if dataclasses.is_dataclass(origin):
        return isinstance(value, dict)
    if isinstance(origin, type):
        return is_instance(value, origin)
    return True


def describe(hint: Any) -> str:
    """``hint`` in words, e.g. ``a number or null``."""
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        return " or ".join(dict.fromkeys(describe(option) for option in typing.get_args(hint)))
    origin, arguments = typing.get_origin(hint) or hint, typing.get_args(hint)
    if origin in (list, tuple, set, frozenset, Sequence):
        return f"a list of {PLURALS.get(arguments[0], 'values')}" if arguments else "a list"
    if origin in (dict, Mapping) or dataclasses.is_dataclass(origin):
        return "a mapping {key: value, ...}"
    if origin is typing.Literal:
        return "one of " + ", ".join(map(str, arguments))
    return WORDS.get(hint, getattr(hint, "__name__", str(hint)))


WORDS = {int: "a whole number", float: "a number", bool: "true or false", str: "text", type(None): "null", None: "null"}
PLURALS = {int: "whole numbers", float: "numbers", bool: "true/false values", str: "names", dict: "mappings"}
