"""Quadrotor: a Crazyflie 2.x rigid body with four motors behind a cascaded velocity controller.

The learner commands a velocity: the action in ``[-1, 1]^3`` times ``max_speed`` (per axis,
world frame). Inside each agent step (``dt``, 20 Hz by default) ``substeps`` physics steps
(240 Hz by default) run the cascade

    velocity error --PI--> desired acceleration (tilt and vertical limits)
      -> thrust vector -> desired attitude (body z along it, yaw held at the reset heading)
      -> attitude error (geometric, on SO(3)) --P--> desired body rates
      -> body-rate error --P, plus gyroscopic feed-forward--> torques
      -> X-configuration mixer -> per-motor thrusts clipped to [0, kf * max_rpm^2] -> motor speeds

and then integrate the rigid body: ``m dv/dt = R e3 sum(f_i) - m g e3 - drag v`` and
``I dw/dt = tau - w x I w`` with quaternion attitude (semi-implicit Euler, renormalised). Motor
speeds follow their command instantly (no motor lag); saturation is the only motor effect.
Constants default to the Crazyflie 2 values of gym-pybullet-drones (``cf2x.urdf``).

State ``(p, v, q, w)``: position, world velocity, unit quaternion ``(w, x, y, z)`` body-to-world,
body rates (13 numbers). Observation (15): position, velocity, the body x axis and the body z
axis in the world frame (six rotation-matrix entries: continuous, no angle wrap), body rates.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from envs.robots.base import Float32Array, FloatArray, Robot, RobotParams
from planner.geometry.world import World


@dataclass(frozen=True)
class QuadrotorParams(RobotParams):
    """Physical constants (Crazyflie 2), controller gains and time steps of the quadrotor."""

    max_speed: float = 1.0
    """Commanded velocity per axis at ``|a| = 1``, in m/s."""
    dt: float = 0.05
    """Agent step in seconds (20 Hz)."""
    substeps: int = 12
    """Physics and control steps per agent step (12 at dt 0.05 s: 240 Hz)."""
    mass: float = 0.027
    """Mass in kg."""
    arm: float = 0.0397
    """Distance from the centre to each motor in m (motors on the diagonals: X layout)."""
    kf: float = 3.16e-10
    """Thrust coefficient: motor thrust = kf * rpm^2, in N/rpm^2."""
    km: float = 7.94e-12
    """Torque coefficient: rotor drag torque = km * rpm^2, in N m/rpm^2."""
    ixx: float = 1.4e-5
    """Moment of inertia about body x, in kg m^2."""
    iyy: float = 1.4e-5
    """Moment of inertia about body y, in kg m^2."""
    izz: float = 2.17e-5
    """Moment of inertia about body z, in kg m^2."""
    gravity: float = 9.81
    """Gravitational acceleration in m/s^2."""
    max_rpm: float = 21702.0
    """Motor speed limit in rpm (thrust-to-weight 2.25 with the default constants)."""
    drag: float = 0.01
    """Linear air drag on the translational velocity, in kg/s."""
    max_tilt: float = 0.5
    """Largest tilt the velocity loop asks for, in rad (limits horizontal acceleration)."""
    max_climb_accel: float = 5.0
    """Largest vertical acceleration the velocity loop asks for, up or down, in m/s^2."""
    vel_kp: float = 4.0
    """Velocity loop proportional gain, in 1/s."""
    vel_ki: float = 2.0
    """Velocity loop integral gain, in 1/s^2."""
    att_kp: float = 10.0
    """Attitude loop gain: desired body rate per radian of attitude error, in 1/s."""
    rate_kp: float = 60.0
    """Body-rate loop gain: angular acceleration per rad/s of rate error, in 1/s."""
    max_rate: float = 10.0
    """Body-rate bound of the observation in rad/s (faster rates are clipped in it)."""

    def check(self) -> None:
        for name in ("max_speed", "dt", "mass", "arm", "kf", "km", "ixx", "iyy", "izz"):
            self.require(getattr(self, name) > 0.0, name, "must be > 0")
        for name in ("gravity", "max_climb_accel", "vel_kp", "att_kp", "rate_kp", "max_rate"):
            self.require(getattr(self, name) > 0.0, name, "must be > 0")
        self.require(self.substeps >= 1, "substeps", "must be an integer >= 1")
        self.require(self.drag >= 0.0, "drag", "must be >= 0")
        self.require(self.vel_ki >= 0.0, "vel_ki", "must be >= 0")
        self.require(0.0 < self.max_tilt < 1.4, "max_tilt", "must lie in (0, 1.4) rad")
        hover = math.sqrt(self.mass * self.gravity / (4.0 * self.kf))
        self.require(self.max_rpm > hover, "max_rpm", f"must exceed the hover speed {hover:.0f}")
        h = self.dt / self.substeps
        self.require(self.rate_kp * h < 1.0, "rate_kp", "times the physics step must be < 1")


class Quadrotor(Robot):
    """Crazyflie-like quadrotor in 3D driven by velocity commands (see the module docstring)."""

    name: ClassVar[str] = "quadrotor"
    workspace_dims: ClassVar[tuple[int, ...]] = (3,)
    params_type: ClassVar[type[RobotParams]] = QuadrotorParams

    def __init__(self, world: World, radius: float, params: QuadrotorParams) -> None:
        super().__init__(world, radius, params)
        self.p = params
        self.state_dim = 15
        self.action_dim = 3
        self.dt = params.dt
        v, w = 2.0 * params.max_speed, params.max_rate
        self.state_low, self.state_high = self._observation_bounds(
            self.bounds[:, 0].tolist() + [-v] * 3 + [-1.0] * 6 + [-w] * 3,
            self.bounds[:, 1].tolist() + [v] * 3 + [1.0] * 6 + [w] * 3,
        )
        self._s = [0.0] * 13
        self._s[6] = 1.0
        self._integral = [0.0, 0.0, 0.0]
        self._yaw = 0.0
        self.rpm = [0.0, 0.0, 0.0, 0.0]
        """Motor speeds of the last physics step, in rpm."""

    def _reset(self, position: FloatArray, heading: float, rng: np.random.Generator) -> None:
        x, y, z = position.tolist()
        half = 0.5 * heading
        self._s = [x, y, z, 0.0, 0.0, 0.0, math.cos(half), 0.0, 0.0, math.sin(half), 0.0, 0.0, 0.0]
        self._integral = [0.0, 0.0, 0.0]
        self._yaw = heading
        hover = math.sqrt(self.p.mass * self.p.gravity / (4.0 * self.p.kf))
        self.rpm = [hover] * 4

    def _step(self, action: list[float]) -> bool:
        p = self.p
        h = p.dt / p.substeps
        m, g, kf, drag = p.mass, p.gravity, p.kf, p.drag
        ixx, iyy, izz = p.ixx, p.iyy, p.izz
        a4 = 4.0 * p.arm / math.sqrt(2.0)
        k4 = 4.0 * p.km / kf
        f_max = kf * p.max_rpm * p.max_rpm
        kv, ki, ka, kr = p.vel_kp, p.vel_ki, p.att_kp, p.rate_kp
        a_xy_max = g * math.tan(p.max_tilt)
        a_z_max = p.max_climb_accel
        i_max = max(a_xy_max, a_z_max) / ki if ki > 0.0 else 0.0
        cx, cy, cz = (a * p.max_speed for a in action)
        cpsi, spsi = math.cos(self._yaw), math.sin(self._yaw)
        px, py, pz, vx, vy, vz, qw, qx, qy, qz, wx, wy, wz = self._s
        ix, iy, iz = self._integral
        f0 = f1 = f2 = f3 = 0.0
        for _ in range(p.substeps):
            # Rotation matrix (body to world) of the current attitude.
            r00 = 1.0 - 2.0 * (qy * qy + qz * qz)
            r01 = 2.0 * (qx * qy - qw * qz)
            r02 = 2.0 * (qx * qz + qw * qy)
            r10 = 2.0 * (qx * qy + qw * qz)
            r11 = 1.0 - 2.0 * (qx * qx + qz * qz)
            r12 = 2.0 * (qy * qz - qw * qx)
            r20 = 2.0 * (qx * qz - qw * qy)
            r21 = 2.0 * (qy * qz + qw * qx)
            r22 = 1.0 - 2.0 * (qx * qx + qy * qy)
            # Velocity loop (PI, anti-windup clamp) -> desired acceleration -> thrust vector.
            ex, ey, ez = cx - vx, cy - vy, cz - vz
            # Clamps written out: min/max calls were a fifth of the step's time.
            ix += ex * h
            ix = i_max if ix > i_max else (-i_max if ix < -i_max else ix)
            iy += ey * h
            iy = i_max if iy > i_max else (-i_max if iy < -i_max else iy)
            iz += ez * h
            iz = i_max if iz > i_max else (-i_max if iz < -i_max else iz)
            ax, ay, az = kv * ex + ki * ix, kv * ey + ki * iy, kv * ez + ki * iz
            a_xy = math.hypot(ax, ay)
            if a_xy > a_xy_max:
                ax, ay = ax * a_xy_max / a_xy, ay * a_xy_max / a_xy
            az = a_z_max if az > a_z_max else (-a_z_max if az < -a_z_max else az)
            fx, fy, fz = m * ax, m * ay, m * (az + g)
            # Desired attitude: body z along the thrust vector, heading held at the reset yaw.
            fn = math.sqrt(fx * fx + fy * fy + fz * fz)
            b3x, b3y, b3z = fx / fn, fy / fn, fz / fn
            b2x, b2y, b2z = -b3z * spsi, b3z * cpsi, b3x * spsi - b3y * cpsi
            n2 = math.sqrt(b2x * b2x + b2y * b2y + b2z * b2z)
            b2x, b2y, b2z = b2x / n2, b2y / n2, b2z / n2
            b1x, b1y, b1z = b2y * b3z - b2z * b3y, b2z * b3x - b2x * b3z, b2x * b3y - b2y * b3x
            thrust = fx * r02 + fy * r12 + fz * r22
            thrust = thrust if thrust > 0.0 else 0.0
            # Attitude error e = vee(Rd^T R - R^T Rd) / 2 -> desired body rates.
            m01 = b1x * r01 + b1y * r11 + b1z * r21
            m02 = b1x * r02 + b1y * r12 + b1z * r22
            m10 = b2x * r00 + b2y * r10 + b2z * r20
            m12 = b2x * r02 + b2y * r12 + b2z * r22
            m20 = b3x * r00 + b3y * r10 + b3z * r20
            m21 = b3x * r01 + b3y * r11 + b3z * r21
            dwx = -0.5 * ka * (m21 - m12)
            dwy = -0.5 * ka * (m02 - m20)
            dwz = -0.5 * ka * (m10 - m01)
            # Body-rate loop with gyroscopic feed-forward -> torques.
            gx = wy * izz * wz - wz * iyy * wy
            gy = wz * ixx * wx - wx * izz * wz
            gz = wx * iyy * wy - wy * ixx * wx
            tx = ixx * kr * (dwx - wx) + gx
            ty = iyy * kr * (dwy - wy) + gy
            tz = izz * kr * (dwz - wz) + gz
            # X mixer: motors at (+,+), (-,+), (-,-), (+,-) arm/sqrt2; diagonal pairs share spin.
            t4, xa, ya, zk = 0.25 * thrust, tx / a4, ty / a4, tz / k4
            f0 = t4 + xa - ya - zk
            f0 = f_max if f0 > f_max else (f0 if f0 > 0.0 else 0.0)
            f1 = t4 + xa + ya + zk
            f1 = f_max if f1 > f_max else (f1 if f1 > 0.0 else 0.0)
            f2 = t4 - xa + ya - zk
            f2 = f_max if f2 > f_max else (f2 if f2 > 0.0 else 0.0)
            f3 = t4 - xa - ya + zk
            f3 = f_max if f3 > f_max else (f3 if f3 > 0.0 else 0.0)
            total = f0 + f1 + f2 + f3
            ux = 0.25 * a4 * (f0 + f1 - f2 - f3)
            uy = 0.25 * a4 * (-f0 + f1 + f2 - f3)
            uz = 0.25 * k4 * (-f0 + f1 - f2 + f3)
            # Rigid body, semi-implicit Euler.
            vx += (r02 * total - drag * vx) / m * h
            vy += (r12 * total - drag * vy) / m * h
            vz += ((r22 * total - drag * vz) / m - g) * h
            px += vx * h
            py += vy * h
            pz += vz * h
            wx += (ux - gx) / ixx * h
            wy += (uy - gy) / iyy * h
            wz += (uz - gz) / izz * h
            hh = 0.5 * h
            qw, qx, qy, qz = (
                qw - hh * (qx * wx + qy * wy + qz * wz),
                qx + hh * (qw * wx + qy * wz - qz * wy),
                qy + hh * (qw * wy - qx * wz + qz * wx),
                qz + hh * (qw * wz + qx * wy - qy * wx),
            )
            qn = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
            qw, qx, qy, qz = qw / qn, qx / qn, qy / qn, qz / qn
        self._s = [px, py, pz, vx, vy, vz, qw, qx, qy, qz, wx, wy, wz]
        self._integral = [ix, iy, iz]
        self.rpm = [math.sqrt(f / kf) for f in (f0, f1, f2, f3)]
        return self._collider.hits((px, py, pz))

    @property
    def state(self) -> FloatArray:
        """``(x, y, z, vx, vy, vz, qw, qx, qy, qz, wx, wy, wz)``."""
        return np.array(self._s)

    def observation(self) -> Float32Array:
        """Position, velocity, body x axis, body z axis (world frame), body rates."""
        px, py, pz, vx, vy, vz, qw, qx, qy, qz, wx, wy, wz = self._s
        return self._clip_observation(
            (
                px,
                py,
                pz,
                vx,
                vy,
                vz,
                1.0 - 2.0 * (qy * qy + qz * qz),
                2.0 * (qx * qy + qw * qz),
                2.0 * (qx * qz - qw * qy),
                2.0 * (qx * qz + qw * qy),
                2.0 * (qy * qz - qw * qx),
                1.0 - 2.0 * (qx * qx + qy * qy),
                wx,
                wy,
                wz,
            )
        )

    def position(self) -> FloatArray:
        return np.array(self._s[:3])

    def heading(self) -> float:
        return self.attitude()[2]

    def attitude(self) -> tuple[float, float, float]:
        """Roll, pitch, yaw in radians (ZYX Euler angles), for plots and tests."""
        qw, qx, qy, qz = self._s[6:10]
        roll = math.atan2(2.0 * (qw * qx + qy * qz), 1.0 - 2.0 * (qx * qx + qy * qy))
        pitch = math.asin(max(-1.0, min(1.0, 2.0 * (qw * qy - qz * qx))))
        yaw = math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
        return roll, pitch, yaw
