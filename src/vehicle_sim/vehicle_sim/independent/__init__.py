"""Independent generator of blind sim-to-real validation bags (issue 22, item 7).

``python -m vehicle_sim.independent --out DIR --per-effect N --controls N --seed S
[--vehicle quarter_car skid_steer] [--structure-controls N] [--out-of-catalogue N]
[--effect E ...] [--duration D] [--jobs 2] [--no-signature]``

A second generator on a separate code path from :mod:`vehicle_sim.tools.withheld`:
its plants, road, soil and tire laws, integrators, sensors and effects are
written here from MODELS.md (A.1, A.2, A.8; B.2–B.6) and import nothing of
:mod:`vehicle_sim.plants`, :mod:`vehicle_sim.effects`, :mod:`vehicle_sim.terrain`
or :mod:`terrain_estimation`. Bags are written with rosbags' own typestore
(:mod:`.messages`). The diagnosis must not import this package
(test/test_independent_generator.py checks both directions).

Plants: :mod:`.quarter_car` (2-DOF, RK4 on an exact FFT road grid, soil laws
linear / hyperbolic / hard-layer / Zener) and :mod:`.skid_steer` (6 wheels,
speed-controlled drive, brush or Dugoff tire, quasi-static equal-spring
loads solved by fixed point, ground plane with grade and bank, numba RK4).
Vehicle data: MODELS.md Tables 1–2, the values of ``config/<vehicle>.yaml``.

Output layout (as the withheld suite)::

    DIR/manifest.json   id → vehicle, bag path (what the diagnosis is given)
    DIR/labels.json     the answers: for the scorer only
    DIR/bags/<id>/      one rosbag2 (MCAP) bag per id; contract topics only, no
                        ground truth, no /clock, stamps from a random start in [1.6e9, 1.8e9] s

Labels per id: ``vehicle``, ``kind`` (``effect``, ``control``,
``structure_control``, ``out_of_catalogue``), ``effect`` (the catalogue's name
of the same physics) and ``parameters`` (the catalogue's parameter names where
they correspond), ``structure`` (soil or tire law), ``out_of_catalogue`` and
its parameters, ``expected`` where the right answer is not an effect name
(``"structure differs"`` for a structure control), ``scenario``, ``seed``,
``duration``, ``start_time_ns``, and ``signature``: the SNR of the bag minus
its twin (same plan, every effect off, same noise) over the response channels
(IMUs), against the noise σ the generator added.

Scenario (drawn per bag)
    quarter car: duration 10–20 s; ISO 8608 road B, C or D (E or F for
    ``wheel_liftoff``), band 0.05–10 cycles/m; soil from MODELS.md Table 1
    (graneville, upland sandy loam, north gower, rubicon; the linear-equivalent
    k_s of each law); speed 6–12 m/s.
    skid steer: duration 15–20 s; manoeuvre ``turn`` (rim speed 1–2.5 m/s,
    side difference ±0.4–1.0 m/s, ramp 2–4 s), ``s_shape`` (3–7 m/s,
    sinusoidal difference 0.3–0.8 m/s, period 5–10 s) or ``straight_then_turn``
    (2–5 m/s, a turn of ±0.3–0.8 m/s difference from 5–8 s); motion-resistance
    coefficient f_rr 0.01–0.04 (a nuisance: the config states 0.02 with a
    tolerance).

Effects and ranges ("log" log-uniform, "±" random sign; one effect per bag)
    quarter car:

    * ``sensor_delay``: one stream (body, wheel accelerometer or profile) late
      by 0.01–0.3 s (log), a FIFO of its samples (parameter
      ``sensor_delay_<stream>``);
    * ``accel_bias``: each accelerometer with probability ½ (at least one),
      ±0.1–0.6 m/s² (log); ``accel_scale``: the same, ±0.03–0.1;
    * ``nonlinear_soil``: hyperbolic (Kondner, softening), static load 0.2–0.6 of
      the ultimate, or hard-layer (stiffening), 0.2–0.6 of the layer compressed
      at rest; local stiffness k_s at the static load in both;
    * ``sprung_mass_change`` ±0.1–0.3 (log); ``tire_damping`` 300–1500 N·s/m
      (log); ``suspension_friction`` 50–250 N (log), F_c (2/π) atan(Δv/0.01 m/s);
    * ``tire_enveloping``: two-point follower, base 0.1–0.3 m (a cosine filter
      of the road, not the catalogue's moving average);
    * ``wheel_liftoff``: unilateral contact, on an E or F road.

    skid steer:

    * ``sensor_delay`` (IMU) or ``wheel_speed_delay`` (encoders): 0.01–0.3 s
      (log), a FIFO on the 1 ms sample grid;
    * ``accel_bias``: each axis with probability ½ (at least one), ±0.1–0.6 m/s²
      (log); ``accel_scale`` per axis ±0.03–0.1; ``gyro_bias`` per axis (z, x,
      y) ±0.005–0.03 rad/s; ``gyro_scale`` (yaw) ±0.03–0.1;
    * ``terrain_grade``: grade and/or bank (each with probability ½, at least
      one), ±0.05–0.2 rad (log);
    * ``tire_relaxation``: lengths L_x 0.1–1.0 m, L_y 0.2–1.5 m (uniform),
      rate √(v_x² + 0.2²)/L;
    * ``friction_change`` 0.4–0.75 or 1.3–1.8; ``cornering_stiffness_change``
      0.4–0.75 or 1.35–2.5; ``wheel_radius_error`` ±0.03–0.08;
    * ``turning_resistance``: F_b = −c_b F_z (2/π) atan(v_y/v_b), c_b 0.1–0.5
      (log), v_b 0.02–0.1 m/s.

Structure-gap controls (``kind`` ``structure_control``, right answer "structure differs")
    nominal driving with only the plant's structure changed: quarter car a
    Zener (viscoelastic) soil, high-frequency stiffness ratio ρ 0.5–2 (log),
    relaxation frequency 2–10 Hz (log); skid steer the Dugoff tire law with
    the nominal C_x, C_α and μ.

Out-of-catalogue effects (none of them in the withheld generator's list)
    on the IMU stream (quarter car ``imu/body``; skid steer ``imu``):
    ``sample_dropouts`` (bursts starting with probability 0.5–2 % per sample,
    3–15 samples long, repeating the last reading), ``accel_lowpass`` (a
    first-order low-pass of the accelerometer readings, cut-off 3–10 Hz quarter
    car, 0.5–2 Hz skid steer, log), ``clock_drift`` (the stream's stamps scaled
    by 1 ± 0.005–0.02).

Reproducible from ``--seed``: each vehicle draws from its own generator
seeded from (seed, vehicle). Progress (one line per bag, with its signature)
goes to stderr.
"""

from __future__ import annotations

__all__ = ["main"]


def main(argv: list[str] | None = None) -> int:
    """The command line (:func:`vehicle_sim.independent.suite.main`)."""
    from vehicle_sim.independent.suite import main as _main

    return _main(argv)
