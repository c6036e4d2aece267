"""Offline tuning of the current, velocity and position loops (``turntable-sim tune``).

One module per idea: ``gains`` (the tuned gain set), ``linear`` (discrete loop transfers,
margins, Bode data, the stability gate), ``baselines`` (classic formulas), ``relay`` (relay
auto-tune on the simulated bench), ``scenarios`` (what the gains are judged on), ``cost``
(cost terms of a closed-loop run), ``evaluate`` (gain sets as one lock-step batch),
``optimise`` (differential evolution, one batch per generation), ``robust`` (worst case over
a plant spread), ``plots`` and ``report``. See docs/tuning.md.
"""
