"""The posterior of the slip law (emcee), sampled after the explanation settled the model.

Runs last before the report: io -> model -> fit -> explain -> posterior -> report.
"""

from ._mcmc import Chain as Chain, autocorr_time as autocorr_time, run_ensemble as run_ensemble
from ._posterior import (
    Posterior as Posterior,
    least_squares_identifiability as least_squares_identifiability,
    tempering as tempering,
    sample_posterior as sample_posterior,
    slip_law_parameters as slip_law_parameters,
)
