"""Predictive priors: what step ``s`` draws its particles from and weighs them against.

- :mod:`~seqbayes.predictive.mixture`: the transition mixture of Eq. (A3) (and the paper's kernel density),
  with :mod:`~seqbayes.predictive.pseudo_marginal` for its subsampled evaluation;
- :mod:`~seqbayes.predictive.history`: the exact prior of static parameters;
- :mod:`~seqbayes.predictive.smc2`: SMC^2 for static and drifting parameters together;
- :mod:`~seqbayes.predictive.paths`: the path-space remedy for prior-data conflict.

The package imports nothing on its own: import the modules.
"""
