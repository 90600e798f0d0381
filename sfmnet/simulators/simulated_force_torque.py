"""A simulated six-axis force/torque sensor calibrated with masses in unknown orientations (method §6)."""

from __future__ import annotations

import torch

from sfmnet.data.calibration_datamodule import CalibrationDataModule
from sfmnet.data.recording import CalibrationData, CalibrationRecording
from sfmnet.errors import SfmnetError
from sfmnet.simulators.simulation import DTYPE, LinearSensor, random_directions
from sfmnet.linalg.wrench import STANDARD_GRAVITY, wrench_map

WRENCH_AXES = ["fx", "fy", "fz", "mx", "my", "mz"]


def configuration_maps(configurations: list[dict], gravity: float) -> torch.Tensor:
    """``C x 3 x 6`` wrench maps of ``[{mass: kg, centre_of_mass: [x, y, z] m}, ...]``."""
    return torch.stack(
        [wrench_map(c["mass"], torch.tensor(c["centre_of_mass"], dtype=DTYPE), gravity) for c in configurations]
    )


class ForceTorqueSensorDataModule(CalibrationDataModule):
    """A linear six-axis sensor with ``channels`` raw channels; masses turned through unknown orientations.

    Each configuration (a mass at a centre of mass) is held in ``samples`` random orientations,
    the first ``known_per_configuration`` of them with their wrench known (poses set on a
    calibrated arm). Recordings: ``rotation`` (the rest unknown) and ``least_squares`` (the same
    rows with every wrench known). ``test``: fresh orientations of every configuration.

    Args:
        channels: ``p`` (at least 6).
        force_gain: raw counts per N (typical channel sensitivity to force).
        torque_gain: raw counts per N m.
        configurations: ``[{mass, centre_of_mass}]``, kg and m; at least three with different
            ``(m, r)`` make all six axes observable.
        samples: orientations per configuration.
        known_per_configuration: how many of them have a known wrench.
        noise_std: electrical noise per channel, counts.
        offset_scale: std of channel offsets, counts.
        test_samples: held-out orientations per configuration.
        gravity: m/s^2.
        seed: fixes the sensor and every recording.
    """

    axes = WRENCH_AXES
    load_unit = "N, N m"

    def __init__(
        self,
        configurations: list[dict],
        channels: int = 8,
        force_gain: float = 10.0,
        torque_gain: float = 200.0,
        samples: int = 24,
        known_per_configuration: int = 3,
        noise_std: float = 1.0,
        offset_scale: float = 300.0,
        test_samples: int = 50,
        gravity: float = STANDARD_GRAVITY,
        seed: int = 0,
        batch_size: int | None = None,
    ) -> None:
        super().__init__(batch_size=batch_size)
        if channels < len(WRENCH_AXES):
            raise SfmnetError(f"data.channels is {channels}: a six-axis sensor needs at least {len(WRENCH_AXES)} channels")
        if known_per_configuration > samples:
            raise SfmnetError(
                f"data.known_per_configuration is {known_per_configuration} but data.samples is {samples}: give at most {samples}"
            )
        self.configurations = configurations
        self.channels = channels
        self.force_gain = force_gain
        self.torque_gain = torque_gain
        self.samples = samples
        self.known_per_configuration = known_per_configuration
        self.noise_std = noise_std
        self.offset_scale = offset_scale
        self.test_samples = test_samples
        self.gravity = gravity
        self.seed = seed

    def build(self) -> CalibrationData:
        generator = torch.Generator().manual_seed(self.seed)
        gains = torch.tensor([self.force_gain] * 3 + [self.torque_gain] * 3, dtype=DTYPE)
        shape = torch.randn(6, self.channels, generator=generator, dtype=DTYPE) * gains[:, None]
        offset = torch.randn(self.channels, generator=generator, dtype=DTYPE) * self.offset_scale
        sensor = LinearSensor(shape=shape, offset=offset, noise_std=self.noise_std)
        maps = configuration_maps(self.configurations, self.gravity)
        rotation = self.session(sensor, maps, self.samples, generator)
        known = torch.arange(len(rotation.readings)) % self.samples < self.known_per_configuration
        loads = torch.where(known[:, None], rotation.true_loads, torch.full_like(rotation.true_loads, float("nan")))
        return CalibrationData(
            recordings={
                "rotation": CalibrationRecording(
                    readings=rotation.readings,
                    loads=loads,
                    true_loads=rotation.true_loads,
                    configuration=rotation.configuration,
                    direction_maps=maps,
                ),
                "least_squares": CalibrationRecording(readings=rotation.readings, loads=rotation.true_loads),
            },
            channels=[f"ch{i}" for i in range(self.channels)],
            axes=list(self.axes),
            load_unit=self.load_unit,
            test=self.session(sensor, maps, self.test_samples, generator),
            truth=sensor.truth(),
        )

    def session(
        self, sensor: LinearSensor, maps: torch.Tensor, samples: int, generator: torch.Generator
    ) -> CalibrationRecording:
        """Every configuration in ``samples`` random orientations, all wrenches given."""
        directions = random_directions(samples * len(maps), 3, generator)
        configuration = torch.arange(len(maps)).repeat_interleave(samples)
        wrenches = torch.einsum("bd,bdn->bn", directions, maps[configuration])
        readings = sensor.read(wrenches, generator)
        return CalibrationRecording(
            readings=readings, loads=wrenches, true_loads=wrenches, configuration=configuration, direction_maps=maps
        )
