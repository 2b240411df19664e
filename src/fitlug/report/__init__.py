"""Reports: fit.json for machines, report.html with plots for people."""

from ._fitjson import fit_json as fit_json
from ._page import write_report as write_report
from ._summary import summary as summary
from ._state import load_state as load_state, save_state as save_state
