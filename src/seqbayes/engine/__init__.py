"""The update as one pipeline (:mod:`~seqbayes.engine.drivers`): weigh, temper/resample/move, evidence,
propagate, record; the sampler's records and settings, the validated likelihood, and the drivers
:class:`~seqbayes.engine.drivers.SMC` and :class:`~seqbayes.engine.drivers.SEMC`.

The package imports nothing on its own: import the modules (``seqbayes.engine.drivers`` ...), or the
public names from :mod:`seqbayes`.
"""
