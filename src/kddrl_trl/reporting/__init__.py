"""Offline reporting: the run records read back (``records``), the statistics over seeds (``stats``), the paper's
claims tested (``verdict``), the figures and the report (``builder``) that ``python -m kddrl_trl.report`` writes.
Nothing here runs during training or evaluation (that is :mod:`kddrl_trl.eval`)."""
