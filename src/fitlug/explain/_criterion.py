"""The criterion an extension of the model must meet to earn its place (catalog effects in
:mod:`._explain`, family terms in :mod:`.families`): Delta BIC = Delta chi^2 + Delta k ln N
below BIC_THRESHOLD, and a strong misfit (chi^2 - dof above STRONG_MISFIT_Z times its spread
from noise alone) must lose at least MIN_SHARE_REMOVED of its excess chi^2 (after a first
catalog effect is taken, any misfit left above LEFT_MISFIT_Z spreads must)."""

BIC_THRESHOLD = -10.0
MIN_SHARE_REMOVED = 0.3
STRONG_MISFIT_Z = 10.0
LEFT_MISFIT_Z = 3.0
#: chi^2/dof at or below which a model extended by family terms counts as modelling the
#: misfit (verdict 'modelled'; above it the terms are reported as partial)
MODELLED_CHI2 = 1.3


def strong_misfit(chi2, dof, spread) -> bool:
    """Whether chi^2's excess over the dof is over STRONG_MISFIT_Z spreads: a strong misfit."""
    return chi2 - dof > STRONG_MISFIT_Z * spread * dof
