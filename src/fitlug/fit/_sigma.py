"""A sigma_mm column that cannot be taken as it stands: holes and absurd values.

The per-sample sigma_mm column sets the fit's weights. Two faults would silently wreck
them, so each is warned about (one line naming the file, the markers and what is done)
and handled:

- empty cells among valid samples: each is filled with its marker's median sigma (its
  role's when the marker has none). With more than half the cells empty the column is
  dropped and the noise comes from the data's 4th differences, as without a column;
- a marker whose sigma_mm claims far more precision than its own scatter shows (the
  noise from its 4th differences more than ABSURD times its median sigma; a sigma of
  1e-9 mm gave a slip error of 2e-12 and chi^2/dof 3e12): its sigma is replaced by that
  measured noise. A sigma larger than the scatter only lowers a marker's weight and is
  kept (a noiseless simulation has no scatter at all).
"""

from __future__ import annotations

import warnings

import numpy as np

from ._noise import fourth_differences, noise_from_differences

ABSURD = 10.0
MIN_DIFFS = 20  # fourth differences a marker needs to judge its own sigma


def check_sigma(rec) -> tuple:
    """`rec` with a usable sigma column (or none), and a list of what was done (strings)."""
    if rec.sigma is None:
        return rec, []
    where = rec.path or "<recording>"
    valid = rec.valid
    sigma = np.array(rec.sigma, float)
    notes = []
    holes = valid & ~np.isfinite(sigma)
    if holes.any():
        n_valid = int(valid.sum())
        names = ", ".join(sorted({rec.markers[m] for m in rec.marker_index[holes].tolist()}))
        if holes.sum() * 2 > n_valid:
            note = (f"sigma_mm is empty in {int(holes.sum())} of {n_valid} valid samples "
                    f"(markers {names}): the column is not used, the noise comes from the "
                    "data's 4th differences")
            warnings.warn(f"{where}: {note}", stacklevel=3)
            return rec.with_(sigma=None), [note]
        for m in np.unique(rec.marker_index[holes]).tolist():
            own = valid & (rec.marker_index == m) & np.isfinite(sigma)
            if not own.any():
                role = np.isin(rec.marker_index, rec.markers_of(rec.roles[m]))
                own = valid & role & np.isfinite(sigma)
            if not own.any():
                own = valid & np.isfinite(sigma)
            sigma[holes & (rec.marker_index == m)] = float(np.median(sigma[own]))
        note = (f"sigma_mm is empty in {int(holes.sum())} valid sample(s) (markers "
                f"{names}): filled with each marker's median sigma_mm")
        warnings.warn(f"{where}: {note}", stacklevel=3)
        notes.append(note)
    fixed = []
    for m in range(rec.n_markers):
        sel = valid & (rec.marker_index == m)
        if sel.sum() < 5:
            continue
        t = rec.t[sel]
        diffs = [fourth_differences(t, rec.x[sel]), fourth_differences(t, rec.y[sel])]
        noise, n = noise_from_differences(diffs)
        claimed = float(np.median(sigma[sel]))
        if n >= MIN_DIFFS and np.isfinite(noise) and noise > ABSURD * claimed:
            sigma[sel] = noise
            fixed.append(f"{rec.markers[m]} ({claimed:.3g} mm claimed, {noise:.3g} mm "
                         "measured)")
    if fixed:
        note = (f"sigma_mm of marker(s) {', '.join(fixed)} is more than {ABSURD:g} times "
                "smaller than the marker's own scatter (4th differences): replaced by the "
                "measured noise")
        warnings.warn(f"{where}: {note}", stacklevel=3)
        notes.append(note)
    if not notes:
        return rec, []
    return rec.with_(sigma=sigma), notes
