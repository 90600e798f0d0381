"""Closed loop on the simulated MK-V: a policy drives the robot in the test rooms from its own sensors (docs/closed_loop.md).

The paper's claim is about behaviour, not agreement: the robot driven by the learnt mapping
"achieved both wandering behavior and escaped stalls and collisions". Here every policy (a
learner's mapping, the teleoperator that made the training data, a seeded random policy) drives
the same robots from the same starts with the same sensor noise, and three figures score each:

- ``moving_fraction``: the fraction of periods in which the drive wheel turns;
- ``escape_rate``: of the incidents (a bump or a stall starting), the fraction followed by free
  motion within ``escape_seconds``;
- ``bumps_per_minute``: how often a bump switch closes.

The definitions, from what :mod:`sfmnet.simulators.mkv_robot` models, are in the functions below.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from sfmnet.data.sensorimotor import Command
from sfmnet.models.sensorimotor_learner import SensorimotorLearner
from sfmnet.simulators.mkv_robot import SENSORS, MkvWorld, Policy, Room, Run, TeleoperatorPolicy, run_policy

BUMP_COLUMNS = [SENSORS.index("bump_front"), SENSORS.index("bump_rear")]


@dataclass(frozen=True)
class ClosedLoopSettings:
    """How long and how often each policy drives, and the escape's time scales.

    Attributes:
        runs_per_room: robots per test room, each from the room's centre with its own heading.
        seconds: length of each run, s of simulated time.
        escape_seconds: an incident is escaped if free motion starts within this time of it, s.
        free_seconds: free motion lasts at least this long, s.
        stall_seconds: the drive commanded and the wheel still for at least this long is a stall, s.
        random_hold_seconds: the random policy keeps each command this long on average, s.
        seed: fixes the headings, the sensor noise and the random policies' draws.
    """

    runs_per_room: int = 3
    seconds: float = 100.0
    escape_seconds: float = 10.0
    free_seconds: float = 1.0
    stall_seconds: float = 0.5
    random_hold_seconds: float = 1.0
    seed: int = 0


def learner_policy(model: SensorimotorLearner, commands: list[Command]) -> Policy:
    """The learnt mapping as a policy: each period the commands read from the latest sensors alone.

    The reading (:meth:`SensorimotorLearner.read_commands`) is a least-squares projection, affine in
    the sensors, so it is taken once as ``vector = offset + sensors @ slope`` (exact to rounding)
    rather than solved anew every period.
    """
    labels = [np.array(command.labels) for command in commands]
    probes = torch.cat([torch.zeros(1, model.sensor_count), torch.eye(model.sensor_count)]).to(model.column_mean.dtype)
    vectors = model.read_commands(probes).reconstruction
    offset, slope = vectors[0], vectors[1:] - vectors[0]

    def policy(sensors: np.ndarray) -> np.ndarray:
        indices = model.decode(offset + torch.from_numpy(sensors) @ slope)
        return np.stack([labels[i][indices[:, i]] for i in range(len(labels))], axis=1)

    return policy


class RandomPolicy:
    """Drive and steer drawn uniformly from {-1, 0, 1}, whatever the sensors say, each robot's pair redrawn with
    probability ``dt / hold_seconds`` per period (held about ``hold_seconds``: redrawn every period it jitters in place)."""

    def __init__(self, robots: int, dt: float, hold_seconds: float, generator: np.random.Generator) -> None:
        self.redraw = min(1.0, dt / hold_seconds)
        self.generator = generator
        self.commands = generator.integers(-1, 2, size=(robots, 2))

    def __call__(self, sensors: np.ndarray) -> np.ndarray:
        redrawn = self.generator.random(len(self.commands)) < self.redraw
        self.commands[redrawn] = self.generator.integers(-1, 2, size=(int(redrawn.sum()), 2))
        return self.commands.copy()


def drive_test_rooms(world: MkvWorld, policy: Policy, settings: ClosedLoopSettings) -> list[Run]:
    """``settings.runs_per_room`` runs in each test room, in lockstep; the same starts and sensor noise for every policy."""
    rooms = [room for room in world.test_rooms for _ in range(settings.runs_per_room)]
    steps = max(1, round(settings.seconds / world.robot.dt))
    return run_policy(rooms, policy, steps, world.robot, np.random.default_rng([settings.seed, 0]))


def policies(world: MkvWorld, learners: dict[str, SensorimotorLearner], commands: list[Command],
             settings: ClosedLoopSettings) -> dict[str, Policy]:
    """Every learner's mapping, then the teleoperator and the random policy (their draws seeded apart from the robots')."""
    driven = {name: learner_policy(model, commands) for name, model in learners.items()}
    robots = len(world.test_rooms) * settings.runs_per_room
    driven["teleoperator"] = TeleoperatorPolicy(robots, world.operator, world.robot.dt, np.random.default_rng([settings.seed, 1]))
    driven["random"] = RandomPolicy(robots, world.robot.dt, settings.random_hold_seconds, np.random.default_rng([settings.seed, 2]))
    return driven


@dataclass(frozen=True)
class ClosedLoopResult:
    """Every policy's runs (test room by test room, ``settings.runs_per_room`` each) and their figures."""

    runs: dict[str, list[Run]]
    metrics: dict[str, dict[str, float]]
    settings: ClosedLoopSettings

    def flat_metrics(self) -> dict[str, float]:
        """``closed_loop/<policy>/<figure>``, for ``metrics.json``."""
        return {f"closed_loop/{policy}/{key}": value for policy, figures in self.metrics.items() for key, value in figures.items()}

    def rooms(self, world: MkvWorld) -> list[tuple[Room, dict[str, list[Run]]]]:
        """Each test room with every policy's runs in it."""
        n = self.settings.runs_per_room
        return [(room, {policy: runs[i * n : (i + 1) * n] for policy, runs in self.runs.items()})
                for i, room in enumerate(world.test_rooms)]


def closed_loop(world: MkvWorld, learners: dict[str, SensorimotorLearner], commands: list[Command],
                settings: ClosedLoopSettings) -> ClosedLoopResult:
    """Every policy of :func:`policies` drives the test rooms; each scored by :func:`closed_loop_metrics`."""
    runs = {name: drive_test_rooms(world, policy, settings) for name, policy in policies(world, learners, commands, settings).items()}
    metrics = {name: closed_loop_metrics(policy_runs, world.robot.dt, world.robot.ticks_per_metre, settings)
               for name, policy_runs in runs.items()}
    return ClosedLoopResult(runs, metrics, settings)


def wheel_turning(run: Run, ticks_per_metre: float) -> np.ndarray:
    """``t`` bool: the drive wheel turned by at least one encoder tick in the period (noise-free)."""
    return np.abs(run.rolled) * ticks_per_metre >= 1


def in_contact(run: Run) -> np.ndarray:
    """``t`` bool: a bump switch (front or rear) was closed at the end of the period."""
    return (run.sensors[:, BUMP_COLUMNS] > 0).any(axis=1)


def onsets(flags: np.ndarray) -> np.ndarray:
    """Indices where ``flags`` (``t`` bool) becomes true (index 0 if it starts true)."""
    return np.flatnonzero(flags & ~np.concatenate([[False], flags[:-1]]))


def sustained(flags: np.ndarray, periods: int) -> np.ndarray:
    """``t`` bool: the periods that belong to a stretch of at least ``periods`` consecutive true ``flags``."""
    edges = np.diff(np.concatenate([[0], flags.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    kept = np.zeros(len(flags), dtype=bool)
    for start, end in zip(starts, ends):
        if end - start >= periods:
            kept[start:end] = True
    return kept


def stalled(run: Run, turning: np.ndarray, periods: int) -> np.ndarray:
    """``t`` bool: the drive motor commanded (drive != 0) with the wheel not turning for ``periods`` or more in a row,
    so its current sits at stall (a reversal passes through zero speed in one period and is no stall)."""
    return sustained((run.commands[:, 0] != 0) & ~turning, periods)


def escapes(incidents: np.ndarray, free: np.ndarray, window: int, lasting: int) -> np.ndarray:
    """Whether each incident was escaped: free motion lasting ``lasting`` periods or more starting within
    ``window`` periods after it.

    Args:
        incidents: indices of the periods where incidents start.
        free: ``t`` bool, the wheel turning with both bump switches open.
        window, lasting: in periods.

    Returns:
        ``len(incidents)``: 1 escaped, 0 not, NaN where the run ended too soon to tell.
    """
    # An incident's own period is never free, so a long stretch seen in the window started there.
    free_stretch = sustained(free, lasting)
    outcome = np.full(len(incidents), np.nan)
    for k, t in enumerate(incidents):
        if free_stretch[t + 1 : t + 1 + window].any():
            outcome[k] = 1.0
        elif t + window + lasting <= len(free):
            outcome[k] = 0.0
    return outcome


def closed_loop_metrics(runs: list[Run], dt: float, ticks_per_metre: float, settings: ClosedLoopSettings) -> dict[str, float]:
    """One policy's runs scored: ``moving_fraction``, ``escape_rate`` (NaN without an incident that can be
    judged), ``bumps_per_minute`` and ``incidents`` (how many the escape rate is over)."""
    periods = {key: round(getattr(settings, key) / dt) for key in ("escape_seconds", "free_seconds", "stall_seconds")}
    turning_steps = bumps = 0
    outcomes = []
    for run in runs:
        turning, contact = wheel_turning(run, ticks_per_metre), in_contact(run)
        turning_steps += int(turning.sum())
        bumps += len(onsets(contact))
        # A bump and the stall it causes start together: one incident.
        incidents = onsets(contact | stalled(run, turning, periods["stall_seconds"]))
        outcomes.append(escapes(incidents, turning & ~contact, periods["escape_seconds"], periods["free_seconds"]))
    judged = np.concatenate(outcomes)
    judged = judged[~np.isnan(judged)]
    steps = sum(len(run.rolled) for run in runs)
    return {
        "moving_fraction": turning_steps / steps,
        "escape_rate": float(judged.mean()) if len(judged) else float("nan"),
        "bumps_per_minute": bumps / (steps * dt / 60),
        "incidents": float(len(judged)),
    }
