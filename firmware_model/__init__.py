"""The STM32F103 firmware model: 500 Hz three-loop servo, safety, command handling.

Modules:

* ``firmware``: :class:`~firmware_model.firmware.Firmware`, the board (``servo_tick``,
  ``current_tick``, ``signals``, ``counters``): states, commands and NACKs, trips, telemetry.
* ``servo``: what the control law computes (encoder unwrap, velocity observer,
  position/velocity/current loops); ``laws/`` holds its variants, one per file: float and
  Q-format fixed point, scalar and batch.
* ``params``: one frozen dataclass per TOML table, ``TABLES``, ``FirmwareParams``, the
  default gains derived from the nominal plant.
* ``stability``: the linear check behind ``NackCode.UNSTABLE_GAINS``.
* ``fixedpoint``: saturating int32 Q16.16 / Q8.24 helpers.
* ``units``: the unit suffixes and the bench's fixed ratios.
"""
