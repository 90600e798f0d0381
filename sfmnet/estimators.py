"""The primordial learners (paper section 6, method §8) as estimators in scikit-learn's conventions.

``fit(sensors, commands)`` runs the same learner, config and trainer as
``python -m sfmnet train experiment=sensorimotor_csv`` (on every row given, none held out);
``predict`` reads commands from sensors alone; fitted attributes end in ``_``.
"""

from __future__ import annotations

import math
import warnings
from typing import Any

import numpy as np
import torch

from sfmnet.api import as_matrix, compose_run_config
from sfmnet.data.rows import IMPLAUSIBLE
from sfmnet.data.table_columns import column_names, require_same_row_labels
from sfmnet.errors import SfmnetError

LEARNERS = {"eigenspace": "eigenspace", "autoencoder": "linear_autoencoder"}
# Each parameter's config key (the longest first, so that one key is not replaced inside another).
PARAMETER_KEYS = {"rank_rule": "model.rank_rule", "rank": "model.rank", "seed": "model.seed", "max_epochs": "trainer.max_epochs"}


class CommandLearner:
    """Learn a robot's sensor-to-command mapping from teleoperated samples: a subspace of ``[sensors; one-hot commands]``.

    Args:
        learner: ``"eigenspace"`` (affine PCA, the paper's learner) or ``"autoencoder"`` (the linear autoencoder).
        rank: ``k``, the subspace's dimension; None chooses it by ``rank_rule``.
        rank_rule: ``"parallel_analysis"`` (Horn) or ``"largest_ratio"`` (the paper's).
        seed: for the rank rule's permutations and the autoencoder's start.
        max_epochs: the trainer's epochs (None: the learner's config).

    Attributes (after :meth:`fit`):
        rank_: the subspace's dimension.
        labels_: per command channel, its labels in column order.
        basis_: ``k x m`` rows spanning the subspace (standardised units, ``m`` = sensors + one-hot columns).
        mean_, scale_: ``m``, the standardisation of ``[sensors; one-hot commands]``.
        singular_values_: of the standardised training vectors.
        n_features_in_: ``p_s``, the sensors.
        feature_names_in_: the sensors' column names, where ``sensors`` was a table (a pandas DataFrame); a table given
            to ``predict`` is then read by those names, in any order, and an array in their order, with a warning.
        learner_: the fitted :class:`~sfmnet.models.sensorimotor_learner.SensorimotorLearner`.

    The confidence is ``1 / (1 + e)``, ``e`` the sensors' misfit to the subspace: with a rank at least
    the number of sensors every sensor vector fits and the confidence is 1 everywhere; it discriminates
    only when the subspace is smaller than the sensor space (choose ``rank`` below ``p_s``).

    Example::

        learner = CommandLearner().fit(sensors, commands)   # (f, p_s) floats, (f, c) labels
        commands = learner.predict(new_sensors)              # (f, c) labels
        confidence = learner.predict_confidence(new_sensors) # (f,) in (0, 1]
    """

    def __init__(
        self,
        learner: str = "eigenspace",
        rank: int | None = None,
        rank_rule: str = "parallel_analysis",
        seed: int = 0,
        max_epochs: int | None = None,
    ) -> None:
        self.learner = learner
        self.rank = rank
        self.rank_rule = rank_rule
        self.seed = seed
        self.max_epochs = max_epochs

    def get_params(self, deep: bool = True) -> dict[str, Any]:
        return {name: getattr(self, name) for name in ("learner", "rank", "rank_rule", "seed", "max_epochs")}

    def set_params(self, **params: Any) -> CommandLearner:
        for name, value in params.items():
            if name not in self.get_params():
                raise SfmnetError(f"CommandLearner has no parameter '{name}': use one of {', '.join(self.get_params())}")
            setattr(self, name, value)
        return self

    def fit(self, sensors: Any, commands: Any) -> CommandLearner:
        """Learn from ``sensors`` (``f x p_s``, numbers) and ``commands`` (``f x c`` or ``f``, any labels)."""
        from hydra.utils import instantiate

        from sfmnet.data.sensorimotor import Command, Episode, FixedSensorimotorDataModule, SensorimotorData, label_indices
        from omegaconf import OmegaConf

        from sfmnet.cli import unwrapped_user_errors
        from sfmnet.config_values import check_config
        from sfmnet.readers.sensorimotor_csv import sort_key
        from sfmnet.training.fitting import fit
        from sfmnet.training.run import quiet_lightning

        if self.learner not in LEARNERS:
            raise SfmnetError(f"learner is '{self.learner}': use one of {', '.join(LEARNERS)}")
        require_same_row_labels({"sensors": sensors, "commands": commands})
        names = column_names(sensors, "sensors")
        readings = finite_matrix(sensors, "sensors")
        labels = np.asarray(commands, dtype=object)
        labels = labels[:, None] if labels.ndim == 1 else labels
        if labels.ndim != 2 or len(labels) != len(readings):
            raise SfmnetError(f"commands has shape {labels.shape}: give one row of command labels per sensor row ({len(readings)})")
        missing = [(r, c) for r, c in zip(*np.nonzero(np.vectorize(is_missing, otypes=[bool])(labels)))]
        if missing:
            raise SfmnetError(
                f"commands has {len(missing)} missing labels (None or NaN; first: row {missing[0][0]}, column "
                f"{missing[0][1]}): every row needs its command, so drop those rows or label them"
            )
        # The command line's label order (numbers first), so both fit the same columns.
        alphabets = [sorted(set(labels[:, i].tolist()), key=sort_key) for i in range(labels.shape[1])]
        codes = np.stack([label_indices(labels[:, i], alphabet) for i, alphabet in enumerate(alphabets)], axis=1)
        data = SensorimotorData(
            train=[Episode(readings, codes)],
            test=[],
            sensors=[str(name) for name in names] if names else [f"s{i}" for i in range(readings.shape[1])],
            commands=[Command(f"c{i}", alphabet) for i, alphabet in enumerate(alphabets)],
        )
        overrides = {PARAMETER_KEYS[name]: getattr(self, name) for name in PARAMETER_KEYS}
        if self.max_epochs is None:
            del overrides["trainer.max_epochs"]
        try:
            cfg = compose_run_config(["experiment=sensorimotor_csv", f"model={LEARNERS[self.learner]}"], overrides)
            # The data come as arrays here, not from cfg.data: check the rest.
            check_config(OmegaConf.masked_copy(cfg, [key for key in cfg if key != "data"]))
            torch.manual_seed(self.seed)
            with unwrapped_user_errors():
                model = instantiate(cfg.model)
            quiet_lightning()
            fit(model, cfg, FixedSensorimotorDataModule(data), logger=False, enable_checkpointing=False, callbacks=[],
                enable_progress_bar=False)
        except SfmnetError as error:
            # The command line's keys, in the words of this class's parameters.
            message = str(error)
            for name, key in PARAMETER_KEYS.items():
                message = message.replace(key, name)
            raise SfmnetError(message) from None
        self.learner_ = model
        self.labels_ = alphabets
        self.rank_ = int(model.rank)
        self.basis_ = model.basis().detach().numpy()
        self.mean_, self.scale_ = model.column_mean.numpy(), model.column_scale.numpy()
        self.singular_values_ = model.singular_values.numpy()
        self.n_features_in_ = readings.shape[1]
        if names is not None:
            self.feature_names_in_ = np.array(names, dtype=object)
        elif hasattr(self, "feature_names_in_"):
            del self.feature_names_in_
        return self

    def _read(self, sensors: Any) -> Any:
        if not hasattr(self, "learner_"):
            raise SfmnetError("this CommandLearner is not fitted yet: call fit(sensors, commands) first")
        names = column_names(sensors, "sensors")
        readings = finite_matrix(sensors, "sensors")
        fitted = list(getattr(self, "feature_names_in_", []))
        if names is None and fitted:
            warnings.warn(
                f"sensors has no column names, but the learner was fitted on named columns ({', '.join(map(str, fitted))}): "
                "they are read in that order", UserWarning, stacklevel=3,
            )
        if names is not None and fitted and names != fitted:
            # By name, as apply matches a calibration's channels: a table's columns in another order are no other sensors.
            missing = [name for name in fitted if name not in names]
            if missing:
                raise SfmnetError(
                    f"sensors has no column {', '.join(map(str, missing))}: the learner was fitted on columns "
                    f"{', '.join(map(str, fitted))}"
                )
            readings = readings[:, [names.index(name) for name in fitted]]
        if readings.shape[1] != self.n_features_in_:
            raise SfmnetError(f"sensors has {readings.shape[1]} columns but the learner was fitted on {self.n_features_in_}")
        return self.learner_.read_commands(torch.from_numpy(readings))

    def predict(self, sensors: Any) -> np.ndarray:
        """Commands read from ``sensors`` alone (``f x p_s``): ``f x c`` labels (``f`` when fitted on one channel)."""
        reading = self._read(sensors)
        labels = np.stack(
            [np.asarray(alphabet, dtype=object)[reading.commands[:, i]] for i, alphabet in enumerate(self.labels_)], axis=1
        )
        return labels[:, 0] if len(self.labels_) == 1 else labels

    def predict_confidence(self, sensors: Any) -> np.ndarray:
        """``1 / (1 + e)``, ``e`` the RMS standardised misfit of the sensors to the subspace: ``f`` values in (0, 1]."""
        return self._read(sensors).confidence

    def transform(self, sensors: Any) -> np.ndarray:
        """The full ``[sensors; one-hot commands]`` vectors the learner reconstructs from ``sensors``: ``f x m``."""
        return self._read(sensors).reconstruction.numpy()


def finite_matrix(values: Any, name: str) -> np.ndarray:
    """:func:`as_matrix`, refusing NaN and infinite entries (a learner has no use for a missing reading) and values
    beyond the command line's limit (a hostile tester's sensors times 1e160 overflowed the standardisation to inf and
    scored 0.38 with every confidence 1)."""
    array = as_matrix(values, name)
    bad = np.argwhere(~np.isfinite(array))
    if len(bad):
        raise SfmnetError(
            f"{name} has {len(bad)} NaN or infinite values (first: row {bad[0][0]}, column {bad[0][1]}): "
            "drop those rows or fill them in"
        )
    huge = np.argwhere(np.abs(array) > IMPLAUSIBLE)
    if len(huge):
        raise SfmnetError(
            f"{name} has {len(huge)} values beyond {IMPLAUSIBLE:.0e} (first: row {huge[0][0]}, column {huge[0][1]}): "
            "a corrupt value or a unit slip; repair them or rescale the column"
        )
    return array


def is_missing(label: Any) -> bool:
    return label is None or (isinstance(label, float) and math.isnan(label))
