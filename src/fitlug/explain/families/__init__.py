"""After the catalog, the families (MODEL.md §5): flexible, regularised terms at the
model's places (speed, body, ground, a segment), each a function of one natural coordinate,
kept when they earn their place by the catalog's Delta-BIC criterion.

:func:`discover` fits the families a located mismatch points at on top of a fit;
fitlug.explain calls it when the catalog leaves a located mismatch.
"""

from ._discover import (FAMILIES as FAMILIES, MODELLED_CHI2 as MODELLED_CHI2,
                        after_catalog as after_catalog,
                        Discovery as Discovery, Term as Term, discover as discover)
