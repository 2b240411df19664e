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


#: chi^2/dof of the final fit above which the model is taken not to describe the path
#: (a contact-dynamics track: thousands on the engine's recordings) and the slip is read
#: off the straight runs (explain._straight) where the recording allows it. The engine's
#: recordings end at 1 100-9 500 (docs/engine.md); physics outside the catalog on
#: kinematic recordings mostly ends below it (bench_discovery: 1.0-1.7 after), and where
#: not (a clock wobble, a strong cogging) the straight runs still measure the slip: it is
#: the ratio of two measured mean speeds. Above it, too, the final fit runs no glitch
#: rounds (explain._final) and the ground profile adds no knots (families._ground)
GROSS_CHI2 = 25.0
