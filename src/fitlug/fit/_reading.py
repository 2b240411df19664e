"""What a fit's `robust` (set by fitlug.explain._robust) says about how its slip is read:
the two tests explain and posterior share."""

from __future__ import annotations


def reads_straight_runs(res) -> bool:
    """Whether `res`'s headline slip is read off the straight runs (its `robust`, set by
    fitlug.explain._robust): its model does not describe the path and its slip law is
    reported not identifiable. The one test of it (explain and posterior use it)."""
    return (getattr(res, "robust", None) or {}).get("headline") == "straight runs"


def misses_the_data(res) -> bool:
    """Whether `res`'s model misses the markers by so much that its slip is not read and no
    straight run reads it (fitlug.explain._straight.far_from_data): its slip and slip law
    are reported not identifiable, the reason in res.robust["far_from_data"]."""
    return bool((getattr(res, "robust", None) or {}).get("far_from_data"))
