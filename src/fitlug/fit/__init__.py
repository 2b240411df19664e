"""Least-squares fit (optimistix) of the track model; the posterior is `fitlug.posterior`."""

from ._fit import (
    fit as fit,
    fit_problem as fit_problem,
    free_parameters as free_parameters,
    refit_noise as refit_noise,
    residual_noise as residual_noise,
    reweighted as reweighted,
)
from ._covariance import covariance as covariance
from ._lsq import least_squares as least_squares
from ._residuals import residuals as residuals
from ._noise import estimate_noise as estimate_noise
from ._problem import Problem as Problem, build_problem as build_problem
from ._parameters import (
    Parameter as Parameter,
    Parameters as Parameters,
    Prior as Prior,
    parameters as parameters,
)
from ._result import Estimate as Estimate, FitResult as FitResult, derived as derived
from ._predict import Band as Band, Prediction as Prediction
from ._batch import fit_many as fit_many

from .._callable import make_callable as _make_callable

_make_callable(__name__)  # `fitlug.fit(...)` calls the function even when bound to this module
