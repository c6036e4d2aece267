"""The reproduction of seed 000's experiments (Fig. 6, Fig. 7, Fig. 8 / Table 1), seed 002's
Tables 1-2, and the extras (S-curve, look-ahead): ``turntable-sim reproduce``.

One module per idea: ``experiments`` (loading, variants, running, the decoded
:class:`~sim.reproduce.experiments.Trace`), ``metrics``, ``plots``, one module per figure
(``fig6``, ``fig7``, ``fig8``), ``seed002``, ``scurve_extras``, ``lookahead_demo``,
``report`` (REPORT.md) and ``pipeline`` (all of it, as the command runs it).
"""

from sim.reproduce.pipeline import FIGURES, ReproduceOutput, reproduce

__all__ = ["FIGURES", "ReproduceOutput", "reproduce"]
