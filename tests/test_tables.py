"""MBL tables: grid accuracy against direct LWR, lookup paths, clamping, file format and its errors."""

# ruff: noqa: N803, N806  (matrix names X, Xq as in the module under test)

import json
import pickle
from pathlib import Path

import numpy as np
import pytest
from scipy.interpolate import RegularGridInterpolator

from hexgym.mbl.table import FORMAT_VERSION, MBLTable, TableFileError, dataset_hash, load_table
from hexgym_lab.mbl.baselines import SPOOL_STEP, SYNTH_INPUTS, synthetic_flow_sharing
from hexgym_lab.mbl.grid import benchmark_lookup, build_table, suggest_axes
from hexgym_lab.mbl.lwr import LocallyWeightedRegression, LWRParams, default_scales

STEPS = (SPOOL_STEP, SPOOL_STEP, None, None)


@pytest.fixture(scope="module")
def data() -> tuple[np.ndarray, np.ndarray]:
    return synthetic_flow_sharing(1500, seed=5)


@pytest.fixture(scope="module")
def params(data: tuple[np.ndarray, np.ndarray]) -> LWRParams:
    X, _ = data
    return LWRParams(0.25, tuple(default_scales(X) * [0.7, 0.9, 1.0, 1.5]), 0.05)


@pytest.fixture(scope="module")
def table(data: tuple[np.ndarray, np.ndarray], params: LWRParams) -> MBLTable:
    X, y = data
    axes = suggest_axes(X, params, steps=STEPS, max_total=60_000)
    return build_table("boom", SYNTH_INPUTS, "boom_velocity", X, y, params, axes, seed=1)


def _inside(table: MBLTable, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    lo, hi = [a[0] for a in table.axes], [a[-1] for a in table.axes]
    return rng.uniform(lo, hi, size=(n, len(lo)))


def test_axes_put_spools_on_the_sampling_levels(table: MBLTable) -> None:
    np.testing.assert_allclose(table.axes[0], np.arange(-11, 12) * 1e-3, atol=1e-15)
    np.testing.assert_allclose(table.axes[1], np.arange(-11, 12) * 1e-3, atol=1e-15)
    assert 2 < len(table.axes[2]) <= 41 and table.values.size <= 60_000


def test_metrics_and_grid_error_small(table: MBLTable, data: tuple[np.ndarray, np.ndarray]) -> None:
    X, y = data
    m = table.metrics
    assert m["n_points"] == len(y) and table.data_hash == dataset_hash(X, y)
    assert 0 < m["loo_rmse_rel"] < 0.1 and 0 < m["holdout_rmse_rel"] < 0.1
    assert m["grid_rmse_rel"] < 0.5 * m["holdout_rmse_rel"]  # the grid costs less than the learning error
    # independent check at fresh random points inside the data
    lwr = LocallyWeightedRegression(table.params).fit(X, y)
    Xq = _inside(table, 400, seed=9)
    assert np.sqrt(np.mean((table.lookup(Xq) - lwr.predict(Xq)) ** 2)) < 0.03 * np.ptp(y)


def test_lookup_paths_equal_regular_grid_interpolator(table: MBLTable) -> None:
    rgi = RegularGridInterpolator(table.axes, table.values, method="linear")
    Xq = _inside(table, 300, seed=2)
    Xq[:5] = [a[3] for a in table.axes]  # exactly on nodes
    Xq[5] = [a[-1] for a in table.axes]  # the far corner
    expected = rgi(Xq)
    np.testing.assert_allclose(table.lookup(Xq), expected, rtol=0, atol=1e-13)
    single = np.array([table(list(x)) for x in Xq])
    np.testing.assert_allclose(single, expected, rtol=0, atol=1e-13)
    np.testing.assert_allclose(table(Xq[7]), expected[7], rtol=0, atol=1e-13)  # a 1-D numpy query


def test_non_uniform_axes_match_the_reference() -> None:
    rng = np.random.default_rng(3)
    axes = (np.array([0.0, 0.1, 0.5, 2.0]), np.array([-1.0, 1.0]), np.cumsum(rng.uniform(0.1, 1.0, 6)))
    values = rng.standard_normal(tuple(len(a) for a in axes))
    t = MBLTable("t", ("a", "b", "c"), "v", axes, values, np.ones_like(values), LWRParams(1.0, (1.0, 1.0, 1.0)))
    Xq = rng.uniform([0, -1, axes[2][0]], [2, 1, axes[2][-1]], (200, 3))
    expected = RegularGridInterpolator(axes, values)(Xq)
    np.testing.assert_allclose(t.lookup(Xq), expected, atol=1e-13)
    np.testing.assert_allclose([t(list(x)) for x in Xq], expected, atol=1e-13)


def test_linear_data_gives_an_exact_table() -> None:
    rng = np.random.default_rng(4)
    X = rng.uniform([-0.011, -0.011, -1e5, 0], [0.011, 0.011, 4e5, 2e5], (800, 4))
    coef = np.array([8.0, -3.0, 2e-7, -1e-7])
    y = X @ coef + 0.01
    params = LWRParams(0.5, tuple(default_scales(X)), ridge=0.0)
    t = build_table("lin", SYNTH_INPUTS, "v", X, y, params, suggest_axes(X, params, max_total=20_000))
    Xq = _inside(t, 200, seed=1)
    np.testing.assert_allclose(t.lookup(Xq), Xq @ coef + 0.01, rtol=0, atol=1e-10)
    assert t.metrics["loo_rmse_rel"] < 1e-10 and t.metrics["grid_rmse_rel"] < 1e-10


def test_outside_queries_clamp_and_lose_confidence(table: MBLTable) -> None:
    centre = [0.5 * (a[0] + a[-1]) for a in table.axes]
    out = np.array([centre, centre, centre])
    out[1, 0] = 0.05  # spool far past its 11 mm end
    out[2, 2] = -1e7  # a load far below the data
    values, conf = table.lookup(out, return_confidence=True)
    clamped = np.clip(out, [a[0] for a in table.axes], [a[-1] for a in table.axes])
    np.testing.assert_allclose(values, table.lookup(clamped), atol=0)
    assert conf[0] > 2 and conf[1] == 0 and conf[2] == 0
    assert table(list(out[1])) == pytest.approx(values[1], abs=1e-14)


def test_nan_query_refused(table: MBLTable) -> None:
    q = [0.0, 0.0, float("nan"), 0.0]
    with pytest.raises(ValueError, match="NaN at column 2"):
        table(q)
    with pytest.raises(ValueError, match="NaN at row 1, column 2"):
        table.lookup(np.array([[0.0] * 4, q]))
    with pytest.raises(ValueError, match="inf at column 0"):
        table(np.array([np.inf, 0.0, 0.0, 0.0]))


def test_pickle_round_trip(table: MBLTable) -> None:
    copy = pickle.loads(pickle.dumps(table))
    Xq = _inside(table, 20, seed=3)
    np.testing.assert_array_equal(copy.lookup(Xq), table.lookup(Xq))
    assert copy(list(Xq[0])) == table(list(Xq[0]))


def test_save_load_round_trip(table: MBLTable, tmp_path: Path) -> None:
    path = table.save(tmp_path / "boom.npz")
    loaded = load_table(path)
    assert [p.name for p in tmp_path.iterdir()] == ["boom.npz"]  # no temporary file left behind
    assert (loaded.name, loaded.inputs, loaded.output) == (table.name, table.inputs, table.output)
    assert loaded.params == table.params and loaded.metrics == table.metrics
    assert loaded.data_hash == table.data_hash and loaded.content_hash() == table.content_hash()
    for a, b in zip(loaded.axes, table.axes, strict=True):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(loaded.values, table.values)
    np.testing.assert_array_equal(loaded.confidence, table.confidence)
    Xq = _inside(table, 50, seed=6)
    np.testing.assert_array_equal(loaded.lookup(Xq), table.lookup(Xq))
    table.save(path)  # overwriting in place works
    assert load_table(path).content_hash() == table.content_hash()


def _rewrite(path: Path, change) -> None:
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    meta = json.loads(str(arrays["meta"][0]))
    change(meta, arrays)
    arrays["meta"] = np.array([json.dumps(meta)])
    with open(path, "wb") as fh:
        np.savez_compressed(fh, **arrays)


def test_wrong_version_names_file(table: MBLTable, tmp_path: Path) -> None:
    path = table.save(tmp_path / "t.npz")
    _rewrite(path, lambda meta, arrays: meta.update(format_version=FORMAT_VERSION + 1))
    with pytest.raises(TableFileError, match=rf"{path}.*format version {FORMAT_VERSION + 1}"):
        load_table(path)


def test_tampered_array_detected(table: MBLTable, tmp_path: Path) -> None:
    path = table.save(tmp_path / "t.npz")

    def tamper(meta, arrays):
        arrays["values"] = arrays["values"].copy()
        arrays["values"][(0,) * arrays["values"].ndim] += 1e-9

    _rewrite(path, tamper)
    with pytest.raises(TableFileError, match=rf"{path}.*content hash mismatch"):
        load_table(path)


def test_wrong_shape_detected(table: MBLTable, tmp_path: Path) -> None:
    path = table.save(tmp_path / "t.npz")
    _rewrite(path, lambda meta, arrays: arrays.update(confidence=arrays["confidence"][:-1]))
    with pytest.raises(TableFileError, match=rf"{path}.*'confidence' has shape"):
        load_table(path)
    table.save(path)
    _rewrite(path, lambda meta, arrays: arrays.pop("axis_2"))
    with pytest.raises(TableFileError, match=rf"{path}.*'axis_2' is missing"):
        load_table(path)


def test_missing_and_corrupt_files(tmp_path: Path) -> None:
    missing = tmp_path / "nope.npz"
    with pytest.raises(FileNotFoundError, match=str(missing)):
        load_table(missing)
    corrupt = tmp_path / "bad.npz"
    corrupt.write_bytes(b"PK\x03\x04 definitely not a zip archive")
    with pytest.raises(TableFileError, match=rf"{corrupt}.*corrupt"):
        load_table(corrupt)


def test_invalid_table_rejected() -> None:
    axes = (np.array([0.0, 1.0]), np.array([0.0, 1.0, 2.0]))
    p = LWRParams(1.0, (1.0, 1.0))
    with pytest.raises(ValueError, match="values has shape"):
        MBLTable("t", ("a", "b"), "v", axes, np.zeros((3, 2)), np.zeros((2, 3)), p)
    with pytest.raises(ValueError, match="increasing"):
        MBLTable("t", ("a", "b"), "v", (axes[0], axes[1][::-1]), np.zeros((2, 3)), np.zeros((2, 3)), p)


def test_benchmark_reports_all_timings(table: MBLTable, data: tuple[np.ndarray, np.ndarray]) -> None:
    X, y = data
    lwr = LocallyWeightedRegression(table.params).fit(X, y)
    times = benchmark_lookup(table, lwr, _inside(table, 100, seed=8), repeats=50)
    assert set(times) >= {"direct_batch_s", "grid_batch_s", "direct_single_s", "grid_single_s", "rgi_single_s"}
    assert all(v > 0 for v in times.values())
