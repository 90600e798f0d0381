"""A simulated MK-V: a three-wheeled non-holonomic robot teleoperated through a cluttered room (method §9).

One drive wheel and one steered wheel turned by a steering motor (tricycle kinematics:
heading rate ``v tan(delta) / L``), three-valued drive and steer commands with no closed-loop
control. Sensors: drive-wheel encoder increments, steering encoder, a two-axis compass,
front and rear bump switches, and the two motor currents, which rise towards stall when the
robot is blocked or the steering sits at a stop. A teleoperator wanders forward with steering
pulses, pauses now and then, and after a bump backs off with steering.

Every draw comes from a ``numpy.random.Generator``, so a seed fixes rooms and episodes.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from sfmnet.data.sensorimotor import (
    Command,
    Episode,
    SensorimotorData,
    SensorimotorDataModule,
    label_indices,
)

SENSORS = [
    "drive_encoder",  # ticks per step (signed, quadrature)
    "steer_encoder",  # steering angle, degrees
    "compass_x",  # horizontal field components: cos and sin of the heading
    "compass_y",
    "bump_front",  # switches, 0 or 1
    "bump_rear",
    "drive_current",  # A, unsigned (a sense resistor sees magnitude only)
    "steer_current",  # A, unsigned
]
COMMANDS = ["drive", "steer"]


@dataclass(frozen=True)
class RobotParameters:
    """The MK-V's physical and sensor parameters (SI units unless named).

    Attributes:
        wheelbase: ``L``, m. radius: body radius for contact, m.
        max_speed: drive speed at full command, m/s. drive_time_constant: first-order motor lag, s.
        max_steer_deg: steering stop, degrees. steer_rate_deg: steering motor speed, deg/s.
        ticks_per_metre: drive encoder resolution. steer_resolution_deg: steering encoder step.
        stall_current / free_current: drive motor current blocked / at full speed, A.
        steer_stall_current / steer_run_current: steering motor current at a stop / turning, A.
        current_noise, compass_noise, encoder_noise: sensor noise std (A, field units, ticks).
        dt: control and sampling period, s.
    """

    wheelbase: float = 0.30
    radius: float = 0.22
    max_speed: float = 0.30
    drive_time_constant: float = 0.30
    max_steer_deg: float = 35.0
    steer_rate_deg: float = 60.0
    ticks_per_metre: float = 2000.0
    steer_resolution_deg: float = 1.0
    stall_current: float = 2.0
    free_current: float = 0.4
    steer_stall_current: float = 0.8
    steer_run_current: float = 0.3
    current_noise: float = 0.05
    compass_noise: float = 0.03
    encoder_noise: float = 1.0
    dt: float = 0.1


@dataclass(frozen=True)
class OperatorParameters:
    """The teleoperator's habits (rates per second, durations in seconds).

    Attributes:
        steer_rate: how often a steering pulse starts while cruising.
        steer_duration: ``[min, max]`` of a pulse.
        pause_rate: how often the operator stops driving for a moment.
        pause_duration: ``[min, max]`` of a pause.
        backoff_duration: ``[min, max]`` of reversing after a front bump.
        backoff_steer_probability: chance of steering while reversing.
    """

    steer_rate: float = 0.4
    steer_duration: tuple[float, float] = (0.3, 1.5)
    pause_rate: float = 0.05
    pause_duration: tuple[float, float] = (0.5, 2.0)
    backoff_duration: tuple[float, float] = (1.0, 2.5)
    backoff_steer_probability: float = 0.8


@dataclass(frozen=True)
class Room:
    """A rectangle ``[0, width] x [0, depth]`` (m) with circular obstacles (``k x 3``: x, y, radius)."""

    width: float
    depth: float
    obstacles: np.ndarray

    def collides(self, x: float, y: float, radius: float) -> bool:
        if x < radius or y < radius or x > self.width - radius or y > self.depth - radius:
            return True
        if len(self.obstacles) == 0:
            return False
        distance = np.hypot(self.obstacles[:, 0] - x, self.obstacles[:, 1] - y)
        return bool((distance < self.obstacles[:, 2] + radius).any())


def random_room(
    generator: np.random.Generator, size: tuple[float, float], obstacles: int, obstacle_radius: tuple[float, float]
) -> Room:
    """A room with ``obstacles`` non-overlapping round obstacles, leaving the centre free for the start."""
    width, depth = size
    placed: list[tuple[float, float, float]] = []
    for _ in range(obstacles * 50):
        if len(placed) == obstacles:
            break
        r = generator.uniform(*obstacle_radius)
        x, y = generator.uniform(r, width - r), generator.uniform(r, depth - r)
        clear_of_start = math.hypot(x - width / 2, y - depth / 2) > r + 0.8
        apart = all(math.hypot(x - ox, y - oy) > r + orad + 0.6 for ox, oy, orad in placed)
        if clear_of_start and apart:
            placed.append((x, y, r))
    return Room(width, depth, np.array(placed, dtype=float).reshape(-1, 3))


class Teleoperator:
    """Wander forward with random steering pulses and pauses; after a front bump, reverse with steering."""

    def __init__(self, parameters: OperatorParameters, dt: float, generator: np.random.Generator) -> None:
        self.p = parameters
        self.dt = dt
        self.rng = generator
        self.mode = "cruise"
        self.remaining = 0.0
        self.steer = 0

    def command(self, bump_front: bool, bump_rear: bool) -> tuple[int, int]:
        """The (drive, steer) command for this step, each in {-1, 0, 1}."""
        p, rng = self.p, self.rng
        if bump_front and self.mode != "backoff":
            self.start("backoff", p.backoff_duration)
            self.steer = int(rng.choice([-1, 1])) if rng.random() < p.backoff_steer_probability else 0
        elif bump_rear and self.mode == "backoff":
            self.start("cruise", (0.0, 0.0))
        if self.mode in ("backoff", "pause", "pulse"):
            self.remaining -= self.dt
            if self.remaining <= 0:
                self.mode, self.steer = "cruise", 0
        if self.mode == "cruise":
            if rng.random() < p.pause_rate * self.dt:
                self.start("pause", p.pause_duration)
            elif rng.random() < p.steer_rate * self.dt:
                self.start("pulse", p.steer_duration)
                self.steer = int(rng.choice([-1, 1]))
        drive = {"cruise": 1, "pulse": 1, "pause": 0, "backoff": -1}[self.mode]
        steer = self.steer if self.mode in ("pulse", "backoff") else 0
        return drive, steer

    def start(self, mode: str, duration: tuple[float, float]) -> None:
        self.mode = mode
        self.remaining = float(self.rng.uniform(*duration))


@dataclass(frozen=True)
class RobotState:
    """Where the robot is and what its motors are doing.

    Attributes:
        x, y: position, m. heading: rad. delta: steering angle, rad. speed: drive speed, m/s (signed).
    """

    x: float
    y: float
    heading: float
    delta: float = 0.0
    speed: float = 0.0


def rest_reading(state: RobotState) -> np.ndarray:
    """The sensors (``8``, see :data:`SENSORS`) of a robot standing still with its motors off, noise-free:
    what a policy reads before the first command."""
    return np.array([0.0, math.degrees(state.delta), math.cos(state.heading), math.sin(state.heading), 0, 0, 0, 0])


def advance(
    room: Room, state: RobotState, drive: int, steer: int, robot: RobotParameters, noise: list[float]
) -> tuple[RobotState, list[float], float]:
    """One period ``robot.dt`` under the command ``(drive, steer)``, each in {-1, 0, 1}.

    Args:
        noise: ``6`` standard normal draws for the sensor noise.

    Returns:
        The new state; the sensors read at the end of the period (``8`` values, see :data:`SENSORS`), so
        they show what the command is doing; and how far the drive wheel rolled (m, signed, 0 when
        the robot was blocked).
    """
    # Steering motor: integrates the command up to the stops.
    max_delta = math.radians(robot.max_steer_deg)
    wanted = state.delta + steer * math.radians(robot.steer_rate_deg) * robot.dt
    at_stop = steer != 0 and abs(wanted) > max_delta
    delta = max(-max_delta, min(max_delta, wanted))
    # Drive motor: first-order lag towards the commanded speed.
    speed = state.speed + (drive * robot.max_speed - state.speed) * robot.dt / robot.drive_time_constant
    step = speed * robot.dt
    heading = state.heading + step * math.tan(delta) / robot.wheelbase
    x, y = state.x + step * math.cos(heading), state.y + step * math.sin(heading)
    blocked = room.collides(x, y, robot.radius)
    # The switch on the side the robot was moving towards closes; the wheel stops.
    bump_front, bump_rear = blocked and step > 0, blocked and step < 0
    if blocked:
        speed, step = 0.0, 0.0
        x, y, heading = state.x, state.y, state.heading
    if drive != 0:
        drive_current = robot.free_current + (robot.stall_current - robot.free_current) * (1 - abs(speed) / robot.max_speed)
    else:
        drive_current = 0.0
    steer_current = (robot.steer_stall_current if at_stop else robot.steer_run_current) if steer else 0.0
    sensors = [
        round(step * robot.ticks_per_metre + robot.encoder_noise * noise[0]),
        robot.steer_resolution_deg * round(math.degrees(delta) / robot.steer_resolution_deg),
        math.cos(heading) + robot.compass_noise * noise[1],
        math.sin(heading) + robot.compass_noise * noise[2],
        float(bump_front),
        float(bump_rear),
        abs(drive_current + robot.current_noise * noise[3]),
        abs(steer_current + robot.current_noise * noise[4]),
    ]
    return RobotState(x, y, heading, delta, speed), sensors, step


# Reads every robot's latest sensors (``b x 8``, see :data:`SENSORS`) and gives their commands
# (``b x 2``: drive, steer in {-1, 0, 1}).
Policy = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class Run:
    """One robot's run, a row per period.

    Attributes:
        sensors: ``t x 8`` (see :data:`SENSORS`), read at the end of each period.
        commands: ``t x 2``, drive and steer applied during each period, in {-1, 0, 1}.
        poses: ``t x 3``, x and y (m) and heading (rad) at the end of each period.
        rolled: ``t``, how far the drive wheel rolled in each period (m, signed, noise-free).
        room: where it ran.
    """

    sensors: np.ndarray
    commands: np.ndarray
    poses: np.ndarray
    rolled: np.ndarray
    room: Room


def run_policy(
    rooms: list[Room], policy: Policy, steps: int, robot: RobotParameters, generator: np.random.Generator
) -> list[Run]:
    """One robot in each of ``rooms``, from the room's centre with a random heading, all driven by ``policy``
    in lockstep for ``steps`` periods: each period the policy reads every robot's latest sensors (before
    the first, the noise-free reading at rest) and its commands are applied for one period.

    ``generator`` draws the headings, then each period every robot's sensor noise (after the policy,
    which may draw from it too: the teleoperator does).
    """
    states = [RobotState(room.width / 2, room.depth / 2, generator.uniform(-math.pi, math.pi)) for room in rooms]
    latest = np.stack([rest_reading(state) for state in states])
    sensors = np.empty((len(rooms), steps, len(SENSORS)))
    commands = np.empty((len(rooms), steps, len(COMMANDS)))
    poses = np.empty((len(rooms), steps, 3))
    rolled = np.empty((len(rooms), steps))
    for t in range(steps):
        commands[:, t] = policy(latest)
        noise = generator.normal(size=(len(rooms), 6)).tolist()
        for i, (room, (drive, steer)) in enumerate(zip(rooms, commands[:, t].tolist())):
            states[i], sensors[i, t], rolled[i, t] = advance(room, states[i], int(drive), int(steer), robot, noise[i])
            poses[i, t] = states[i].x, states[i].y, states[i].heading
        latest = sensors[:, t]
    return [Run(sensors[i], commands[i], poses[i], rolled[i], room) for i, room in enumerate(rooms)]


class TeleoperatorPolicy:
    """One :class:`Teleoperator` per robot, each reading its robot's bump switches."""

    def __init__(self, robots: int, parameters: OperatorParameters, dt: float, generator: np.random.Generator) -> None:
        self.operators = [Teleoperator(parameters, dt, generator) for _ in range(robots)]
        self.bumps = [SENSORS.index("bump_front"), SENSORS.index("bump_rear")]

    def __call__(self, sensors: np.ndarray) -> np.ndarray:
        front, rear = self.bumps
        return np.array(
            [operator.command(row[front] > 0, row[rear] > 0) for operator, row in zip(self.operators, sensors.tolist())]
        )


def simulate_episode(
    room: Room,
    steps: int,
    robot: RobotParameters,
    operator: OperatorParameters,
    generator: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """One teleoperated run from the room's centre.

    Returns:
        ``sensors`` (``steps x 8``, see :data:`SENSORS`) and ``commands`` (``steps x 2``:
        drive, steer in {-1, 0, 1}); the sensors of step ``t`` are read after applying the
        command of step ``t`` for one period, so they show what that command is doing.
    """
    (run,) = run_policy([room], TeleoperatorPolicy(1, operator, robot.dt, generator), steps, robot, generator)
    return run.sensors, run.commands


@dataclass(frozen=True)
class MkvWorld:
    """What closed-loop evaluation needs of the simulator: the test rooms, the robot and the teleoperator."""

    test_rooms: list[Room]
    robot: RobotParameters
    operator: OperatorParameters


class MkvDataModule(SensorimotorDataModule):
    """Teleoperated MK-V runs: training rooms and different test rooms, all fixed by ``seed``.

    Args:
        train_rooms / test_rooms: how many rooms of each kind.
        episodes_per_room: runs per room, each from the centre with a random heading.
        steps: samples per run (``robot.dt`` apart).
        room_size: ``[width, depth]``, m.
        obstacles: round obstacles per room; obstacle_radius: ``[min, max]``, m.
        robot: :class:`RobotParameters` fields; operator: :class:`OperatorParameters` fields.
        seed: fixes every room and run (test rooms use a different stream).
    """

    def __init__(
        self,
        train_rooms: int = 4,
        test_rooms: int = 2,
        episodes_per_room: int = 3,
        steps: int = 1000,
        room_size: tuple[float, float] = (8.0, 6.0),
        obstacles: int = 6,
        obstacle_radius: tuple[float, float] = (0.2, 0.5),
        robot: dict | None = None,
        operator: dict | None = None,
        seed: int = 0,
        batch_size: int | None = None,
    ) -> None:
        super().__init__(batch_size=batch_size)
        self.train_rooms = train_rooms
        self.test_rooms = test_rooms
        self.episodes_per_room = episodes_per_room
        self.steps = steps
        self.room_size = tuple(room_size)
        self.obstacles = obstacles
        self.obstacle_radius = tuple(obstacle_radius)
        self.robot = RobotParameters(**(robot or {}))
        self.operator = OperatorParameters(**{k: tuple(v) if isinstance(v, list) else v for k, v in (operator or {}).items()})
        self.seed = seed

    def build(self) -> SensorimotorData:
        commands = [Command(name, [-1, 0, 1]) for name in COMMANDS]
        train_stream, test_stream = np.random.default_rng(self.seed).spawn(2)
        train, _ = self.episodes(self.train_rooms, train_stream)
        test, test_rooms = self.episodes(self.test_rooms, test_stream)
        return SensorimotorData(
            train=train,
            test=test,
            sensors=list(SENSORS),
            commands=commands,
            period=self.robot.dt,
            world=MkvWorld(test_rooms, self.robot, self.operator),
        )

    def episodes(self, rooms: int, generator: np.random.Generator) -> tuple[list[Episode], list[Room]]:
        """``episodes_per_room`` teleoperated runs in each of ``rooms`` new rooms; and the rooms."""
        runs, made = [], []
        for _ in range(rooms):
            room = random_room(generator, self.room_size, self.obstacles, self.obstacle_radius)
            made.append(room)
            for _ in range(self.episodes_per_room):
                sensors, commands = simulate_episode(room, self.steps, self.robot, self.operator, generator)
                codes = np.stack([label_indices(column, [-1, 0, 1]) for column in commands.T], axis=1)
                runs.append(Episode(sensors, codes))
        return runs, made
