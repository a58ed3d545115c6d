"""The core layer below the engine, the predictive priors and the moves: the records a step hands from stage to
stage (:mod:`~seqbayes.core.state`), the protocols that join them, the one tempering loop with its mutation
protocol (:mod:`~seqbayes.core.tempering`), the validated likelihood (:mod:`~seqbayes.core.likelihood`) and the
errors (:mod:`~seqbayes.core.errors`).

The package imports nothing on its own: import the modules.
"""
