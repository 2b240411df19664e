"""The base model of MODEL.md §2 in plain numpy (same layout and parameters as fitlug.model),
for the scipy comparison in bench_fit.py."""

import numpy as np


def predict(p, lay):
    Bn, dBn, Bm, dBm = lay.dense_bases()
    grid, h = np.asarray(lay.grid), float(lay.h)
    c = p["v"]
    v0n, a0n, v0m, a0m = Bn @ c, dBn @ c, Bm @ c, dBm @ c
    vtn = v0n / (1 - (p["s0"] + p["beta"] * a0n))
    vtm = v0m / (1 - (p["s0"] + p["beta"] * a0m))
    cum = lambda fn, fm: np.r_[0.0, np.cumsum(h / 6 * (fn[:-1] + 4 * fm + fn[1:]))]  # noqa: E731
    X, psi = cum(v0n, v0m), cum(vtn, vtm)

    def herm(t, y, dy):
        u = (t - grid[0]) / h
        i = np.clip(np.floor(u).astype(int), 0, len(grid) - 2)
        tau = u - i
        t2, t3 = tau * tau, tau ** 3
        return ((2 * t3 - 3 * t2 + 1) * y[i] + (t3 - 2 * t2 + tau) * h * dy[i]
                + (-2 * t3 + 3 * t2) * y[i + 1] + (t3 - t2) * h * dy[i + 1])

    z = np.zeros(1)
    X = X - herm(z, X, v0n)
    psi = psi - herm(z, psi, vtn)
    tl, tb = np.asarray(lay.lug_t), np.asarray(lay.body_t)
    R, D, e = p["R"], p["D"], p["e"]
    P = 2 * D + 2 * np.pi * R
    u = np.mod(p["sigma0"][np.asarray(lay.lug_i)] + herm(tl, psi, vtn), P)
    re = R + e
    b1, b2, b3 = D, D + np.pi * R, 2 * D + np.pi * R
    phr, phf = (u - D) / R, (u - b3) / R
    px = np.select([u < b1, u < b2, u < b3], [D / 2 - u, -D / 2 - re * np.sin(phr), -D / 2 + (u - b2)],
                   D / 2 + re * np.sin(phf))
    py = np.select([u < b1, u < b2, u < b3], [-e + 0 * u, R - re * np.cos(phr), 2 * R + e + 0 * u],
                   R + re * np.cos(phf))
    lx = herm(tl, X, v0n) + p["x_off"] + px
    ly = p["y_off"] + py
    j = np.asarray(lay.body_j)
    bx = herm(tb, X, v0n) + p["cx"][j]
    by = p["cy"][j] + 0 * tb
    return lx, ly, bx, by


def residuals(flat, packing, lay, obs):
    p, i = {}, 0
    for k, shape, n in zip(packing.names, packing.shapes, packing.sizes):
        p[k] = flat[i:i + n].reshape(shape) if shape else flat[i]
        i += n
    lx, ly, bx, by = predict(p, lay)
    o = {k: np.asarray(v) for k, v in obs.items()}
    return np.concatenate([(lx - o["lug_x"]) * o["lug_w"], (ly - o["lug_y"]) * o["lug_w"],
                           (bx - o["body_x"]) * o["body_w"], (by - o["body_y"]) * o["body_w"]])
