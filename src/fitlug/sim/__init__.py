"""Simulated recordings with known truth (MODEL.md §2 and any catalog effects)."""

from ._profile import speed_profile as speed_profile
from ._scenario import REFERENCE_SLIP as REFERENCE_SLIP, Scenario as Scenario
from ._simulate import (
    rig_of as rig_of,
    scenario_from_json as scenario_from_json,
    simulate as simulate,
    truth_params as truth_params,
    write_simulation as write_simulation,
)
from ._campaign import (
    LIMIT_GROUNDS as LIMIT_GROUNDS,
    LIMIT_K as LIMIT_K,
    Run as Run,
    campaign_scenarios as campaign_scenarios,
    law_slip as law_slip,
    law_slope as law_slope,
    limit_runs as limit_runs,
    simulate_campaign as simulate_campaign,
    simulate_points as simulate_points,
)
