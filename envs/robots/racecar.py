"""Racecar: the MIT racecar of ``pybullet_data`` driven through its wheel and steering joints.

Each instance owns a PyBullet physics server in DIRECT mode (no GUI) with gravity, a ground
plane, ``racecar/racecar.urdf`` and the world's obstacles as static bodies extruded
``obstacle_height`` up from the plane (``envs.robots.static_bodies``). Regions are added as flat
visual-only bodies (no collision) so that camera images show them. ``close()`` disconnects the
server; nothing is downloaded.

Action ``(a_v, a_w)`` in ``[-1, 1]^2``: target angular velocity ``a_v * max_wheel_speed`` of both
rear wheels (velocity motors with torque ``wheel_force``; reversing allowed, symmetric) and
steering angle ``a_w * max_steering`` of both front hinges (position motors, positive = left).
The front wheels roll freely. One agent step runs ``substeps`` physics steps of
``dt / substeps``.

The workspace point is the middle of the car, ``CENTER_OFFSET`` ahead of the rear axle (the base
link). ``collided()`` is true when, after any physics sub-step, the car touches an obstacle body
(PyBullet contact points), or when the disc of ``radius`` at the middle of the car meets an
inflated obstacle or leaves the bounds, the same test the other robots use. The car's collision
geometry (wheels and sensor boxes) fits in a disc of about ``FOOTPRINT_RADIUS``.

State ``(x, y, theta, v_long, v_lat, yaw_rate)``: the middle of the car, its heading, and its
velocity in the body frame; the observation is ``(x, y, cos theta, sin theta, v_long, v_lat,
yaw_rate)``.
"""

from __future__ import annotations

import contextlib
import math
import os
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from envs.robots.base import Float32Array, FloatArray, Robot, RobotParams
from envs.robots.static_bodies import add_static_bodies, shape_pieces
from planner.geometry.world import World

WHEEL_RADIUS = 0.05
"""Wheel radius of racecar.urdf in m."""
WHEELBASE = 0.325
"""Distance between the rear axle and the steering hinges in racecar.urdf, in m."""
CENTER_OFFSET = 0.18
"""Distance from the base link (rear axle) forward to the middle of the car's geometry, in m."""
FOOTPRINT_RADIUS = 0.27
"""Radius of a disc about the middle of the car that holds its collision geometry, in m."""
REAR_WHEELS = ("left_rear_wheel_joint", "right_rear_wheel_joint")
FRONT_WHEELS = ("left_front_wheel_joint", "right_front_wheel_joint")
STEERING = ("left_steering_hinge_joint", "right_steering_hinge_joint")
OBSTACLE_RGBA = (0.45, 0.45, 0.5, 1.0)
REGION_RGBA = (
    (0.2, 0.6, 1.0, 0.5),
    (1.0, 0.6, 0.1, 0.5),
    (0.3, 0.8, 0.3, 0.5),
    (0.8, 0.3, 0.8, 0.5),
)


@dataclass(frozen=True)
class RacecarParams(RobotParams):
    """Motor limits, time steps and scene settings of the PyBullet racecar."""

    max_wheel_speed: float = 20.0
    """Rear-wheel angular velocity at ``|a_v| = 1`` in rad/s (about 1 m/s with 5 cm wheels)."""
    max_steering: float = 0.5
    """Steering angle at ``|a_w| = 1`` in rad (the hinge limit is 1 rad)."""
    wheel_force: float = 10.0
    """Maximum torque of each rear-wheel velocity motor in N m."""
    steering_force: float = 10.0
    """Maximum torque of each steering position motor in N m."""
    dt: float = 0.1
    """Agent step in seconds."""
    substeps: int = 6
    """Physics steps per agent step (6 at dt 0.1 s: 60 Hz, stable for this car up to ~1 m/s)."""
    solver_iterations: int = 10
    """Constraint solver iterations per physics step (PyBullet's default is 50)."""
    obstacle_height: float = 0.5
    """Height of the extruded obstacles in m (the car is about 0.2 m tall)."""

    def check(self) -> None:
        for name in ("max_wheel_speed", "wheel_force", "steering_force", "dt", "obstacle_height"):
            self.require(getattr(self, name) > 0.0, name, "must be > 0")
        self.require(0.0 < self.max_steering <= 1.0, "max_steering", "must lie in (0, 1] rad")
        self.require(self.substeps >= 1, "substeps", "must be an integer >= 1")
        self.require(self.solver_iterations >= 1, "solver_iterations", "must be an integer >= 1")

    def min_turning_radius(self) -> float:
        """The kinematic turning radius of the middle of the car at full steering (about
        0.62 m by default; the simulated car skids to about 0.72-0.81 m at 0.2-1 m/s)."""
        rear_axle = WHEELBASE / math.tan(self.max_steering)
        return math.hypot(rear_axle, CENTER_OFFSET)


class Racecar(Robot):
    """PyBullet racecar in a 2D workspace (see the module docstring)."""

    name: ClassVar[str] = "racecar"
    workspace_dims: ClassVar[tuple[int, ...]] = (2,)
    params_type: ClassVar[type[RobotParams]] = RacecarParams

    def __init__(self, world: World, radius: float, params: RacecarParams) -> None:
        super().__init__(world, radius, params)
        import pybullet
        import pybullet_data

        self.p = params
        self.state_dim = 7
        self.action_dim = 2
        self.dt = params.dt
        self._pb: Any = pybullet
        v = 2.0 * params.max_wheel_speed * WHEEL_RADIUS
        w = 2.0 * v * math.tan(params.max_steering) / WHEELBASE + 1.0
        (x0, x1), (y0, y1) = self.bounds.tolist()
        self.state_low, self.state_high = self._observation_bounds(
            [x0, y0, -1.0, -1.0, -v, -v, -w], [x1, y1, 1.0, 1.0, v, v, w]
        )
        self._s = [0.0] * 6
        self.client: int = pybullet.connect(pybullet.DIRECT)
        """PyBullet client id of this robot's physics server (for cameras)."""
        if self.client < 0:
            raise RuntimeError("racecar: could not start a PyBullet DIRECT server")
        try:
            self._build(pybullet_data.getDataPath())
        except BaseException:
            self.close()
            raise

    def _build(self, data_path: str) -> None:
        pb, c, prm = self._pb, self.client, self.p
        pb.setGravity(0.0, 0.0, -9.81, physicsClientId=c)
        pb.setTimeStep(prm.dt / prm.substeps, physicsClientId=c)
        pb.setPhysicsEngineParameter(numSolverIterations=prm.solver_iterations, physicsClientId=c)
        plane_shape = pb.createCollisionShape(pb.GEOM_PLANE, physicsClientId=c)
        self.plane: int = pb.createMultiBody(0, plane_shape, physicsClientId=c)
        self.car: int = pb.loadURDF(
            os.path.join(data_path, "racecar", "racecar.urdf"), [0.0, 0.0, 0.0], physicsClientId=c
        )
        """PyBullet body id of the car."""
        joints = {
            pb.getJointInfo(self.car, j, physicsClientId=c)[1].decode(): j
            for j in range(pb.getNumJoints(self.car, physicsClientId=c))
        }
        missing = [n for n in REAR_WHEELS + FRONT_WHEELS + STEERING if n not in joints]
        if missing:
            raise RuntimeError(f"racecar.urdf lacks the joints {missing}")
        self._joints = sorted(joints.values())
        self._rear = [joints[n] for n in REAR_WHEELS]
        self._steer = [joints[n] for n in STEERING]
        for name in FRONT_WHEELS:
            pb.setJointMotorControl2(
                self.car,
                joints[name],
                pb.VELOCITY_CONTROL,
                targetVelocity=0.0,
                force=0.0,
                physicsClientId=c,
            )
        pieces = [
            p for shape in self.world.obstacles for p in shape_pieces(shape, prm.obstacle_height)
        ]
        self.obstacle_bodies: list[int] = add_static_bodies(pb, c, pieces, True, OBSTACLE_RGBA)
        """PyBullet body ids of the obstacles (boxes and balls grouped, meshes one each)."""
        for k, name in enumerate(self.world.region_names):
            rgba = REGION_RGBA[k % len(REGION_RGBA)]
            add_static_bodies(pb, c, shape_pieces(self.world.regions[name], 0.002), False, rgba)

    def _reset(self, position: FloatArray, heading: float, rng: np.random.Generator) -> None:
        pb, c = self._pb, self.client
        x = float(position[0]) - CENTER_OFFSET * math.cos(heading)
        y = float(position[1]) - CENTER_OFFSET * math.sin(heading)
        quat = (0.0, 0.0, math.sin(0.5 * heading), math.cos(0.5 * heading))
        pb.resetBasePositionAndOrientation(self.car, (x, y, 0.0), quat, physicsClientId=c)
        pb.resetBaseVelocity(self.car, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), physicsClientId=c)
        for j in self._joints:
            pb.resetJointState(self.car, j, 0.0, 0.0, physicsClientId=c)
        self._command(0.0, 0.0)
        self._read_state()

    def _command(self, wheel_speed: float, steering: float) -> None:
        pb, c, prm = self._pb, self.client, self.p
        pb.setJointMotorControlArray(
            self.car,
            self._rear,
            pb.VELOCITY_CONTROL,
            targetVelocities=[wheel_speed] * 2,
            forces=[prm.wheel_force] * 2,
            physicsClientId=c,
        )
        pb.setJointMotorControlArray(
            self.car,
            self._steer,
            pb.POSITION_CONTROL,
            targetPositions=[steering] * 2,
            forces=[prm.steering_force] * 2,
            physicsClientId=c,
        )

    def _read_state(self) -> None:
        pb, c = self._pb, self.client
        (bx, by, _), (qx, qy, qz, qw) = pb.getBasePositionAndOrientation(
            self.car, physicsClientId=c
        )
        (vx, vy, _), (_, _, wz) = pb.getBaseVelocity(self.car, physicsClientId=c)
        theta = math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
        ct, st = math.cos(theta), math.sin(theta)
        self._s = [
            bx + CENTER_OFFSET * ct,
            by + CENTER_OFFSET * st,
            theta,
            vx * ct + vy * st,
            -vx * st + vy * ct,
            wz,
        ]

    def _step(self, action: list[float]) -> bool:
        pb, c, prm = self._pb, self.client, self.p
        self._command(action[0] * prm.max_wheel_speed, action[1] * prm.max_steering)
        car, plane = self.car, self.plane
        touched = False
        for _ in range(prm.substeps):
            pb.stepSimulation(physicsClientId=c)
            if not touched:
                for contact in pb.getContactPoints(bodyA=car, physicsClientId=c):
                    if contact[2] != plane:
                        touched = True
                        break
        self._read_state()
        return touched or self._collider.hits(self._s[:2])

    @property
    def state(self) -> FloatArray:
        """``(x, y, theta, v_long, v_lat, yaw_rate)`` of the middle of the car."""
        return np.array(self._s)

    def observation(self) -> Float32Array:
        """``(x, y, cos theta, sin theta, v_long, v_lat, yaw_rate)``."""
        x, y, theta, v_long, v_lat, w = self._s
        return self._clip_observation((x, y, math.cos(theta), math.sin(theta), v_long, v_lat, w))

    def position(self) -> FloatArray:
        return np.array(self._s[:2])

    def heading(self) -> float:
        return float(self._s[2])

    def close(self) -> None:
        """Disconnect this robot's PyBullet server (idempotent)."""
        if self.client >= 0:
            try:
                self._pb.disconnect(physicsClientId=self.client)
            finally:
                self.client = -1
                self._ready = False

    def __del__(self) -> None:
        # A forgotten close() must not leak a physics server for the rest of the process.
        with contextlib.suppress(Exception):
            self.close()
