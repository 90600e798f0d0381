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

from sfmnet.api import calibrate
from sfmnet.calibration import Calibration
from sfmnet.errors import SfmnetError
from sfmnet.estimators import CommandLearner

__all__ = ["Calibration", "CommandLearner", "SfmnetError", "calibrate"]
