"""Rigid-body relations of the rover replay: wheel geometry, cell forces and moments, the wheels' velocities.

:class:`RoverKinematics` is a part of :class:`~terrain_analysis.sim2real.rover.RoverReplay` (its base class):
relations 1–3 of the docstring of :mod:`terrain_analysis.sim2real.rover` that do not involve the soil (the body-frame
vectors to the wheel centres, the cells' forces in the body frame, the gravity moments, the resistive torques from
the wheel rows, and each wheel's estimate of the body velocity from its slip, contact angle and sinking rate).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from terrain_analysis.sim2real.rover_bag import RoverSeries
from terrain_analysis.sim2real.rover_signal import _rotate
from terrain_estimation.models.rover import RoverParams

FloatArray = NDArray[np.float64]


class RoverKinematics:
    """The rigid-body relations of :class:`~terrain_analysis.sim2real.rover.RoverReplay` (module docstring).

    Uses the replay's series, parameters and the encoder-derived rates of its ``_prepare``.
    """

    series: RoverSeries
    params: RoverParams
    _front: FloatArray
    _joint: FloatArray
    _bogie_wheels: FloatArray
    _wheel_rate: FloatArray
    _wheel_accel: FloatArray
    _bogie_rate: FloatArray

    def _geometry(self, q1: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Body-frame O → wheel centre P (N, 3, 2) and bogie-joint → wheel centre B (N, 3, 2; zero for the front)."""
        cached = getattr(self, "_geometry_cache", None)
        if cached is not None and cached[0] is q1:
            return cached[1], cached[2]
        P, B = self._geometry_of(q1)
        self._geometry_cache = (q1, P, B)
        return P, B

    def _geometry_of(self, q1: FloatArray) -> tuple[FloatArray, FloatArray]:
        n = q1.size
        P = np.zeros((n, 3, 2))
        B = np.zeros((n, 3, 2))
        for j in range(2):
            bx, bz = _rotate(q1, np.full(n, self._bogie_wheels[j, 0]), np.full(n, self._bogie_wheels[j, 1]))
            B[:, j, 0], B[:, j, 1] = bx, bz
            P[:, j, 0], P[:, j, 1] = self._joint[0] + bx, self._joint[1] + bz
        P[:, 2, 0], P[:, 2, 1] = self._front[0], self._front[1]
        return P, B

    def _body_forces(self, axial: FloatArray, perp: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Body-frame (F_x, F_z) on each wheel from its cell: R(ε − θ)(F_⊥, F_L), (N, 3) each."""
        q1 = self.series.bogie
        fx = np.empty_like(axial)
        fz = np.empty_like(axial)
        for j in range(3):
            angle = q1 if j < 2 else 0.0
            fx[:, j], fz[:, j] = _rotate(angle, perp[:, j], axial[:, j])
        return fx, fz

    def _resistive_torque(self, effort: FloatArray) -> FloatArray:
        p = self.params
        return effort - p.wheel_damping * self._wheel_rate - p.wheel_gear_inertia * self._wheel_accel

    def _gravity_moments(self, pitch: FloatArray, P: FloatArray, B: FloatArray) -> tuple[FloatArray, FloatArray]:
        """∂V/∂θ and ∂V/∂q1 (N·m) of the bogie CM and the wheels (O is the body CM)."""
        p = self.params
        g = p.gravity
        q1 = self.series.bogie
        n = q1.size
        cx, cz = _rotate(q1, np.full(n, p.bogie_cm_offset[0]), np.full(n, p.bogie_cm_offset[1]))
        # World x of body-frame vector (bx, bz) at pitch θ: bx cos θ + bz sin θ; ∂V/∂φ = −g Σ m x_world.
        cos, sin = np.cos(pitch), np.sin(pitch)

        def world_x(bx: FloatArray, bz: FloatArray) -> FloatArray:
            return bx * cos + bz * sin

        m_b, m_w = p.bogie_mass, p.wheel_mass
        d_theta = -g * (
            m_b * world_x(self._joint[0] + cx, self._joint[1] + cz)
            + m_w * sum(world_x(P[:, j, 0], P[:, j, 1]) for j in range(3))
        )
        d_bogie = -g * (m_b * world_x(cx, cz) + m_w * sum(world_x(B[:, j, 0], B[:, j, 1]) for j in range(2)))
        return d_theta, d_bogie

    def _centre_speed(self, slip: FloatArray, pitch_rate: FloatArray) -> FloatArray:
        """Each wheel centre's speed along the terrain tangent v_j = r_w ω_j (1 − i_j) (eqs. 1–2), (N, 3)."""
        spin = self._wheel_rate + pitch_rate[:, None]
        spin[:, :2] += self._bogie_rate[:, None]
        rim = self.params.wheel_radius * spin
        centre: FloatArray = np.where(slip >= 0.0, rim * (1.0 - slip), rim / (1.0 + np.minimum(slip, 0.0) + 1e-12))
        return centre

    def _body_velocity(
        self,
        slip: FloatArray,
        delta: FloatArray,
        pitch_rate: FloatArray,
        P: FloatArray,
        B: FloatArray,
        sink: tuple[FloatArray, FloatArray] | None = None,
    ) -> tuple[FloatArray, FloatArray]:
        """Each wheel's estimate of the body-frame velocity of O, (ẋ0^R, ż0^R), (N, 3) each (module docstring, 3).

        ``sink``: (ṡ (N, 3), pitch θ (N,)): each centre also moves at −ṡ cos γ along the terrain normal,
        (sin(γ − θ), cos(γ − θ)) in the body frame.
        """
        s = self.series
        centre = self._centre_speed(slip, pitch_rate)
        phi = delta.copy()
        phi[:, :2] += s.bogie[:, None]
        vx = centre * np.cos(phi) - pitch_rate[:, None] * P[:, :, 1]
        vz = -centre * np.sin(phi) + pitch_rate[:, None] * P[:, :, 0]
        if sink is not None:
            across = -sink[0] * np.cos(phi + sink[1][:, None])
            vx += across * np.sin(phi)
            vz += across * np.cos(phi)
        vx[:, :2] -= self._bogie_rate[:, None] * B[:, :2, 1]
        vz[:, :2] += self._bogie_rate[:, None] * B[:, :2, 0]
        return vx, vz
