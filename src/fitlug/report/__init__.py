"""Reports: fit.json for machines, report.html with plots for people."""

from ._fitjson import fit_json as fit_json
