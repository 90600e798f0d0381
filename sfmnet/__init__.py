"""sfmnet: shape from motion as a learning approach (Voyles, Morrow and Khosla), in PyTorch.

Python API (``import sfmnet`` stays light: Lightning and Hydra load only when something is fitted)::

    cal = sfmnet.calibrate(readings, magnitude=9.81, loads=loads)   # (f, p) raw, (f, n) with NaN rows
    cal.apply(new_readings)                                          # (f, n) loads
    cal.save("cal.json"); sfmnet.Calibration.load("cal.json")
    learner = sfmnet.CommandLearner().fit(sensors, commands)      # primordial learning, scikit-learn style
    learner.predict(new_sensors), learner.predict_confidence(new_sensors)

The command line, ``python -m sfmnet train ...``, runs the same code (README).
"""

from __future__ import annotations

from typing import Any

from sfmnet.calibration import Calibration
from sfmnet.errors import SfmnetError

__all__ = ["Calibration", "CommandLearner", "SfmnetError", "calibrate"]


def __getattr__(name: str) -> Any:
    # The estimators load with their first use, so `import sfmnet` stays light.
    if name == "CommandLearner":
        from sfmnet.estimators import CommandLearner

        return CommandLearner
    raise AttributeError(f"module 'sfmnet' has no attribute '{name}'")


def calibrate(*args: Any, **kwargs: Any) -> Calibration:
    from sfmnet.api import calibrate as fit_calibration

    return fit_calibration(*args, **kwargs)


calibrate.__doc__ = "Calibrate a sensor from raw readings; see :func:`sfmnet.api.calibrate` (help(sfmnet.api.calibrate))."
