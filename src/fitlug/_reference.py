"""The reference study's numbers, shared by the simulator and the reports."""

# Eq. 2 of the reference paper: s = (n - 1) dl' / L with n = 8, dl' = 1.4 mm, L = 127 mm
# is 0.0771654...; the paper prints 0.07716 (truncated, not rounded).
REFERENCE_SLIP = 0.07716
