"""posterior.nc written without ArviZ (fitlug.io.write_samples_netcdf) against the file
ArviZ itself writes for the same draws: the same groups, dimensions, coordinates, values,
dtypes, encodings and attributes, and ArviZ reads ours back as its own."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from fitlug.io import write_samples_netcdf


def _az():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        import arviz as az
    return az


def _draws(seed=3, chains=6, draws=11):
    rng = np.random.default_rng(seed)
    post = {"s0": rng.normal(0.07, 1e-3, (chains, draws)),
            "beta": rng.normal(0.0, 1e-4, (chains, draws)),
            "slip": rng.normal(0.077, 2e-6, (chains, draws))}
    post["slip"][2, 5] = np.nan  # a missing draw stays missing
    return post, {"lp": rng.normal(-10, 1, (chains, draws))}


ATTRS = {"inference_library": "emcee", "fitlug_method": "gaussian", "converged": 1,
         "burn_in": 14, "seed": 0, "sampled": "s0,beta", "not_identifiable": "{}",
         "run_id": "abc123"}


def test_same_file_as_arviz(tmp_path):
    import h5py
    import xarray as xr

    az = _az()
    post, stats = _draws()
    ours, theirs = tmp_path / "ours.nc", tmp_path / "theirs.nc"
    write_samples_netcdf(ours, {"posterior": post, "sample_stats": stats}, ATTRS)
    az.from_dict(posterior=post, sample_stats=stats, attrs=ATTRS).to_netcdf(
        str(theirs), engine="h5netcdf")
    for group in ("posterior", "sample_stats"):
        a = xr.open_dataset(ours, group=group, engine="h5netcdf")
        b = xr.open_dataset(theirs, group=group, engine="h5netcdf")
        assert dict(a.sizes) == dict(b.sizes) and list(a.coords) == list(b.coords)
        assert sorted(a.data_vars) == sorted(b.data_vars)
        for k in list(a.data_vars) + list(a.coords):
            assert a[k].dims == b[k].dims and a[k].dtype == b[k].dtype, k
            np.testing.assert_array_equal(a[k].values, b[k].values)
            fa, fb = (np.asarray(x[k].encoding.get("_FillValue", 0)) for x in (a, b))
            np.testing.assert_array_equal(fa, fb)  # NaN for the floats, none for coordinates
        assert set(a.attrs) >= {"created_at"}
        a.close()
        b.close()
    with h5py.File(ours) as fa, h5py.File(theirs) as fb:
        assert set(fa) == set(fb)
        for k, v in ATTRS.items():  # the root's attributes as xarray writes them
            np.testing.assert_array_equal(fa.attrs[k], fb.attrs[k])
            assert np.asarray(fa.attrs[k]).dtype.kind == np.asarray(fb.attrs[k]).dtype.kind


def test_arviz_reads_it(tmp_path):
    az = _az()
    post, stats = _draws(chains=4, draws=50)
    path = tmp_path / "posterior.nc"
    write_samples_netcdf(path, {"posterior": post, "sample_stats": stats}, ATTRS)
    idata = az.from_netcdf(str(path))
    np.testing.assert_array_equal(idata.posterior["s0"].values, post["s0"])
    np.testing.assert_array_equal(idata.sample_stats["lp"].values, stats["lp"])
    assert idata.attrs["run_id"] == "abc123" and int(idata.attrs["converged"]) == 1
    summ = az.summary(idata, var_names=["s0"], kind="diagnostics")  # the report's table
    assert summ.loc["s0", "ess_bulk"] > 0
    assert [p.name for p in tmp_path.iterdir()] == ["posterior.nc"]  # no temporary left


def test_bad_arrays_leave_nothing(tmp_path):
    path = tmp_path / "posterior.nc"
    with pytest.raises(ValueError, match="posterior"):
        write_samples_netcdf(path, {"posterior": {"a": np.zeros((2, 3)), "b": np.zeros((2, 4))}})
    with pytest.raises(ValueError, match="posterior"):
        write_samples_netcdf(path, {"posterior": {"a": np.zeros(3)}})
    with pytest.raises(TypeError, match="attribute"):
        write_samples_netcdf(path, {"posterior": {"a": np.zeros((2, 3))}}, {"x": [1, 2]})
    assert list(tmp_path.iterdir()) == []
