"""The public recordings of a 3D-printed six-axis force/torque sensor (../shared/data/ft_printed_sensor).

60 files ``data_<config>_R<roll>_P<pitch>_Y<yaw>.csv``: 5 mass configurations x 12 static
poses, columns ``Timestamp,Fx,Fy,Fz,Mx,My,Mz,s0..s7``; the wrench columns are computed from
the known mass, centre of mass and arm pose (see the folder's README).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import torch

from sfmnet.data.calibration_datamodule import CalibrationDataModule
from sfmnet.data.recording import CalibrationData, CalibrationRecording
from sfmnet.readers.table_file import check_finite, read_table
from sfmnet.errors import SfmnetError
from sfmnet.linalg.wrench import wrench_map

FILE_NAME = re.compile(r"data_(?P<configuration>\d+)(?:\.0)?_R.*\.csv$")
WRENCH_COLUMNS = ["Fx", "Fy", "Fz", "Mx", "My", "Mz"]
CHANNEL_COLUMNS = [f"s{i}" for i in range(8)]


class FtPrintedSensorDataModule(CalibrationDataModule):
    """Shape from motion on the real sensor: each pose's wrench hidden except on ``known_poses``.

    Recordings: ``rotation`` (the wrench known only on the known poses; the other poses give
    only their configuration's mass and centre of mass) and ``least_squares`` (every wrench
    known: the traditional calibration). Rows are grouped by pose for leave-one-pose-out.

    Args:
        path: the folder of CSV files.
        configurations: ``{<id>: {mass: kg, centre_of_mass: [x, y, z] m}}`` (the README's table).
        use_configurations: which configurations to calibrate from; one gives a 3-axis force
            calibration (a single mass spans only three wrench dimensions), three or more a
            six-axis one.
        axes: 3 (force) or 6 (force and torque).
        known_poses: pose numbers (0-11, in file-name order of the first configuration) whose wrench is known.
        average_poses: one row per pose, the mean of its ~2000 samples (the paper averages
            readings too); False keeps every sample.
        gravity: m/s^2 (the recordings used 9.81).
    """

    def __init__(
        self,
        path: str,
        configurations: dict,
        use_configurations: list[int],
        axes: int = 3,
        known_poses: list[int] | None = None,
        average_poses: bool = True,
        gravity: float = 9.81,
        batch_size: int | None = None,
    ) -> None:
        super().__init__(batch_size=batch_size)
        self.path = Path(path)
        self.configurations = {int(key): value for key, value in configurations.items()}
        self.use_configurations = list(use_configurations)
        self.axes_count = axes
        self.known_poses = list(known_poses or [])
        self.average_poses = average_poses
        self.gravity = gravity

    def build(self) -> CalibrationData:
        if self.axes_count not in (3, 6):
            raise SfmnetError(f"data.axes must be 3 (force) or 6 (force and torque), not {self.axes_count}")
        if self.axes_count == 3 and len(self.use_configurations) != 1:
            raise SfmnetError("a 3-axis calibration uses one mass: give one entry in data.use_configurations")
        readings, wrenches, configuration, poses = self.read_poses()
        held = int(poses.max()) + 1
        absent = [pose for pose in self.known_poses if not 0 <= pose < held]
        if absent:
            # Otherwise a pose number past the files read (some left out) just leaves one known load fewer, and the
            # run fails later on what the remaining known loads cannot fix.
            raise SfmnetError(
                f"data.known_poses names pose {absent[0]}, but {self.path} holds {held} poses (0-{held - 1}, in file-name "
                "order of the first configuration): give pose numbers from that range"
            )
        n = self.axes_count
        known = np.isin(poses, self.known_poses)
        loads = np.where(known[:, None], wrenches[:, :n], np.nan)
        maps = torch.stack(
            [
                wrench_map(entry["mass"], torch.tensor(entry["centre_of_mass"], dtype=torch.float64), self.gravity)
                for entry in (self.configurations[c] for c in self.use_configurations)
            ]
        )
        as_tensor = torch.from_numpy
        shared = {"true_loads": as_tensor(wrenches[:, :n]), "groups": as_tensor(poses)}
        if n == 3:
            rotation = CalibrationRecording(
                as_tensor(readings), as_tensor(loads), magnitude=float(maps[0, 0, 0]), **shared
            )
        else:
            rotation = CalibrationRecording(
                as_tensor(readings), as_tensor(loads), configuration=as_tensor(configuration), direction_maps=maps, **shared
            )
        return CalibrationData(
            recordings={
                "rotation": rotation,
                "least_squares": CalibrationRecording(as_tensor(readings), as_tensor(wrenches[:, :n]), **shared),
            },
            channels=CHANNEL_COLUMNS,
            axes=["fx", "fy", "fz", "mx", "my", "mz"][:n],
            load_unit="N" if n == 3 else "N, N m",
        )

    def read_poses(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Readings ``f x 8``, wrenches ``f x 6``, configuration index ``f`` and pose number ``f``."""
        if not self.path.is_dir():
            raise SfmnetError(f"{self.path} is not a folder of the sensor's CSV files: check data.path")
        files: dict[int, list[Path]] = {}
        for file in sorted(self.path.glob("data_*.csv")):
            match = FILE_NAME.search(file.name)
            if match:
                files.setdefault(int(match["configuration"]), []).append(file)
        missing = [c for c in self.use_configurations if c not in files or c not in self.configurations]
        if missing:
            raise SfmnetError(
                f"configuration {missing[0]} has no data_{missing[0]}.0_*.csv files in {self.path} or no entry in "
                "data.configurations: pick from " + ", ".join(map(str, sorted(set(files) & set(self.configurations))))
            )
        reference: np.ndarray | None = None
        rows = []
        for index, config in enumerate(self.use_configurations):
            for file in files[config]:
                table = read_table(file)
                readings = table.numeric(CHANNEL_COLUMNS, "channel")
                wrenches = table.numeric(WRENCH_COLUMNS, "wrench")
                check_finite(readings, CHANNEL_COLUMNS, table, "reading")
                if self.average_poses:
                    readings, wrenches = readings.mean(axis=0, keepdims=True), wrenches.mean(axis=0, keepdims=True)
                rows.append((readings, wrenches, index, wrenches[0, :3] / np.linalg.norm(wrenches[0, :3])))
            if reference is None:
                reference = np.stack([direction for *_, direction in rows])
        # The same arm poses in every configuration, matched by gravity direction (file names differ slightly).
        readings = np.concatenate([r for r, *_ in rows])
        wrenches = np.concatenate([w for _, w, *_ in rows])
        configuration = np.concatenate([np.full(len(r), c) for r, _, c, _ in rows])
        poses = np.concatenate([np.full(len(r), int(np.argmax(reference @ d))) for r, _, _, d in rows])
        return readings, wrenches, configuration, poses
