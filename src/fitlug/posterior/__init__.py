"""The posterior of the slip law (emcee), sampled after the explanation settled the model.

Runs last before the report: io -> model -> fit -> explain -> posterior -> report.
"""

from ._mcmc import Chain as Chain, autocorr_time as autocorr_time, run_ensemble as run_ensemble
from ._posterior import Posterior as Posterior
from ._identify import least_squares_identifiability as least_squares_identifiability
from ._tempering import tempering as tempering
from ._sample import sample_posterior as sample_posterior
from ._marginal import slip_law_parameters as slip_law_parameters
