"""The on-line monitor (issue 40, docs/environment.md): damage found as what a learned environmental law and a
slowly varying discrepancy cannot explain.

- :mod:`~seqbayes.structural.monitor.law`: the lagged structure temperature, the smooth freezing knee, the prior
  of the static parameters;
- :mod:`~seqbayes.structural.monitor.daily_filter`: the exact per-mode Kalman filters of the linear part (level
  random walk, day effect, coefficients), batched over particles and modes;
- :mod:`~seqbayes.structural.monitor.change`: the change bank, damage summed out exactly over its day, size and
  element (or modes);
- :mod:`~seqbayes.structural.monitor.sampler`: IBIS over the static parameters on the one tempering loop
  (:func:`seqbayes.core.tempering.temper`);
- :mod:`~seqbayes.structural.monitor.table`: the :class:`Monitor` driver and :func:`monitor_table`, the entry
  point of the misspecification matrix; the run store (:mod:`seqbayes.store.monitor`) runs the same updates.
"""

from .model import AlarmRule, MonitorModel, MonitorSettings
from .table import Monitor, MonitorDay, monitor_table, verdicts

__all__ = ["AlarmRule", "Monitor", "MonitorDay", "MonitorModel", "MonitorSettings", "monitor_table", "verdicts"]
