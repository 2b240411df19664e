"""The reference study's numbers, shared by the simulator and the reports."""

# Eq. 2 of the reference paper: s = (n - 1) dl' / L with n = 8, dl' = 1.4 mm, L = 127 mm
# is 0.0771654...; the paper prints 0.07716 (truncated, not rounded).
REFERENCE_SLIP = 0.07716
# the reference study's robot: lugs in contact, load-bearing length (mm), lug pitch (mm)
REFERENCE_N = 8
REFERENCE_L_MM = 127.0
REFERENCE_PITCH_MM = 18.36
# a fitted pitch (no pitch in rig.toml) within this fraction of 18.36 mm is the robot's
PITCH_TOLERANCE = 0.01


def is_reference_rig(n, L_mm, pitch_given=None, pitch_fitted=None) -> bool:
    """Whether a rig is the reference study's robot, so that a slip may be set against the
    paper's 0.07716 (on any other robot the comparison means nothing).

    The rule: n = 8 lugs in contact, L = 127 mm (to 1e-6 mm), and a lug pitch of 18.36 mm:
    as given in rig.toml (to its printed 0.005 mm) or, where none is given, as fitted
    (within 1 %). Without a rig file n and L take the reference's values by default, so
    the pitch is what tells another robot from it then.

    Args:
        n: lugs in contact; L_mm: load-bearing length, mm.
        pitch_given: [track] lug_pitch_mm, mm, or None.
        pitch_fitted: the fitted lug pitch, mm, or None.
    """
    try:
        if int(n) != REFERENCE_N or abs(float(L_mm) - REFERENCE_L_MM) > 1e-6:
            return False
        if pitch_given is not None:
            return abs(float(pitch_given) - REFERENCE_PITCH_MM) <= 0.005
        return (pitch_fitted is not None
                and abs(float(pitch_fitted) / REFERENCE_PITCH_MM - 1.0) <= PITCH_TOLERANCE)
    except (TypeError, ValueError):
        return False
