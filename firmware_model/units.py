"""Unit suffixes and the bench's fixed conversion constants.

Every physical quantity in this project carries its unit in its name. The suffixes,
written once here (as Klipper does at the top of ``toolhead.py``):

=========  ============================  =========  ==============================
suffix     unit                          suffix     unit
=========  ============================  =========  ==============================
``_deg``   degree                        ``_rad``   radian
``_mdeg``  millidegree (paper's "x10^6")  ``_counts`` encoder counts (14 bit)
``_dps``   degree per second             ``_rad_s`` radian per second
``_dps2``  degree per second squared     ``_dps3``  degree per second cubed
``_rpm``   revolution per minute         ``_a``     ampere
``_v``     volt                          ``_ohm``   ohm
``_h``     henry                         ``_nm``    newton metre
``_kgm2``  kilogram square metre         ``_nm_rad`` N*m per radian (stiffness)
``_s``     simulated second              ``_hz``    hertz
``_adc``   12-bit ADC counts             ``_q``     fixed-point raw integer
=========  ============================  =========  ==============================

Kinds of time: ``t_s`` is simulated time, ``tick`` the integer 500 Hz servo count,
``wall_s`` the host clock (host tools and benchmarks only).

The *axis* is the gearmotor's output shaft (the 17-tooth pulley): firmware positions and
velocities (``pos_deg``, ``vel_dps``) are in axis degrees unless a name says ``motor_`` or
``platter_``. See ``docs/model.md`` for why this is the reading of the paper's units.
"""

from __future__ import annotations

import math

ENCODER_BITS = 14
ENCODER_COUNTS_PER_REV = 1 << ENCODER_BITS  # AS5048: 16384
GEAR_RATIO = 80.0  # planetary gearbox, motor turns per output turn
BELT_RATIO = 85.0 / 17.0  # timing belt, output turns per platter turn
TOTAL_RATIO = GEAR_RATIO * BELT_RATIO  # 400: motor turns per platter turn

DEG_PER_RAD = 180.0 / math.pi
RAD_PER_DEG = math.pi / 180.0
MDEG_PER_DEG = 1000.0

# One motor encoder count in axis degrees: 360 / (16384 * 80) = 2.7466e-4 deg. In the
# fixed-point control law (Q16.16 axis degrees) it is exactly 18 raw units.
AXIS_DEG_PER_COUNT = 360.0 / (ENCODER_COUNTS_PER_REV * GEAR_RATIO)
# Motor rad/s per axis deg/s: 80 * pi / 180 = 1.396.
MOTOR_RAD_S_PER_AXIS_DPS = GEAR_RATIO * RAD_PER_DEG
