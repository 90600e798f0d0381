"""Closed loop on the simulated MK-V (docs/closed_loop.md): the metric definitions, and a learner really driving."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from sfmnet.eval.closed_loop import (
    ClosedLoopSettings,
    closed_loop_metrics,
    drive_test_rooms,
    learner_policy,
)
from sfmnet.models.eigenspace_learner import EigenspaceLearner
from sfmnet.simulators.mkv_robot import SENSORS, MkvDataModule, Room, Run

DT, TICKS_PER_METRE = 0.1, 2000.0


def hand_made_run() -> Run:
    """40 periods (4 s), phase by phase: (periods, drive command, wheel travel in m, closed bump switch)."""
    phases = [
        (5, 1, 0.01, None),  # 0-4 free forward
        (3, 1, 0.0, "bump_front"),  # 5-7 pushing an obstacle: bump A
        (2, -1, -0.01, None),  # 8-9 backing off, too short to be free motion
        (3, -1, 0.0, "bump_rear"),  # 10-12 backed into something: bump B
        (5, 1, 0.01, None),  # 13-17 free: escapes A (8 periods after it) and B (3 after)
        (2, 1, 0.0002, None),  # 18-19 under a tick a period: not turning, too short for a stall
        (3, 1, 0.01, None),  # 20-22 free
        (5, 1, 0.0, None),  # 23-27 drive on, wheel still, no switch: stall C
        (2, 1, 0.01, None),  # 28-29 free but short
        (6, 0, 0.0, None),  # 30-35 stopped (the motor off: no stall); C never escaped within its 10 periods
        (2, 1, 0.01, None),  # 36-37 free but short
        (2, 1, 0.0, "bump_front"),  # 38-39 bump D, too near the end to judge
    ]
    sensors, commands, rolled = [], [], []
    for periods, drive, travel, switch in phases:
        for _ in range(periods):
            row = np.zeros(len(SENSORS))
            if switch:
                row[SENSORS.index(switch)] = 1.0
            sensors.append(row)
            commands.append([drive, 0])
            rolled.append(travel)
    steps = len(rolled)
    room = Room(8.0, 6.0, np.zeros((0, 3)))
    return Run(np.array(sensors), np.array(commands, dtype=float), np.zeros((steps, 3)), np.array(rolled), room)


def test_metric_definitions_on_a_hand_made_run():
    settings = ClosedLoopSettings(escape_seconds=1.0, free_seconds=0.3, stall_seconds=0.3)
    metrics = closed_loop_metrics([hand_made_run()], DT, TICKS_PER_METRE, settings)
    # Turning: 0-4, 8-9, 13-17, 20-22, 28-29, 36-37 (the 0.2 mm periods are under one encoder tick).
    assert metrics["moving_fraction"] == pytest.approx(19 / 40)
    # Bumps A, B, D in 4 s.
    assert metrics["bumps_per_minute"] == pytest.approx(3 / (4 / 60))
    # A and B escaped, C not; D left out.
    assert metrics["incidents"] == 3
    assert metrics["escape_rate"] == pytest.approx(2 / 3)


@pytest.fixture(scope="module")
def small_world():
    data = MkvDataModule(train_rooms=2, test_rooms=1, episodes_per_room=2, steps=1000).build()
    learner = EigenspaceLearner()
    learner.initialise(data)
    return data, learner


def test_the_learner_drives_from_its_own_sensors(small_world):
    """Every command applied is the learner's reading of the sensors just before; it moves where a stopped robot does not."""
    data, learner = small_world
    settings = ClosedLoopSettings(runs_per_room=2, seconds=20.0)
    policy = learner_policy(learner, data.commands)
    runs = drive_test_rooms(data.world, policy, settings)
    stopped = drive_test_rooms(data.world, lambda sensors: np.zeros((len(sensors), 2)), settings)
    labels = np.array([-1, 0, 1])
    for run in runs:
        read = learner.read_commands(torch.from_numpy(run.sensors[:-1])).commands
        assert np.array_equal(run.commands[1:], labels[read])
    driven = closed_loop_metrics(runs, DT, TICKS_PER_METRE, settings)
    still = closed_loop_metrics(stopped, DT, TICKS_PER_METRE, settings)
    assert still["moving_fraction"] == 0
    assert driven["moving_fraction"] > 0.05
    assert not np.allclose(runs[0].poses, stopped[0].poses)


def test_every_policy_starts_alike(small_world):
    """The same starts and sensor noise for every policy: the comparison is of the policies alone."""
    data, _ = small_world
    settings = ClosedLoopSettings(runs_per_room=2, seconds=1.0)
    first = drive_test_rooms(data.world, lambda sensors: np.zeros((len(sensors), 2)), settings)
    second = drive_test_rooms(data.world, lambda sensors: np.zeros((len(sensors), 2)), settings)
    assert np.array_equal(first[0].sensors, second[0].sensors)
    assert not np.array_equal(first[0].poses[:, 2], first[1].poses[:, 2])
