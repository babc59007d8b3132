"""`hexgym bench`: the issue's speed figures (env steps/s, vector env, real-time factors) in one process."""

import json

import pytest

from hexgym.model.plugin import native_available
from hexgym_lab import bench
from hexgym_lab.bench import interleaved_steps_per_second, steps_per_second, vector_steps_per_second
from hexgym_lab.cli import main

KEYS = (
    "learned_realtime_factor_python",
    "hexloading_steps_per_s",
    "hopper_steps_per_s",
    "vector_steps_per_s",
    "circuit_realtime_factor_python",
)
NATIVE_KEYS = (
    "learned_realtime_factor_native",
    "paper_realtime_factor_native",
    "batch_realtime_factor_native",
    "batch_realtime_factor_native_1thread",
    "batch_speedup",
)


def test_bench_command_prints_and_writes_consistent_json(tmp_path, capsys):
    out = tmp_path / "bench.json"
    assert main(["bench", "--steps", "30", "--seconds", "0.05", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "HexLoading-v0" in printed and "Hopper-v5" in printed and "ratio" in printed and "vector" in printed
    data = json.loads(out.read_text())
    keys = KEYS + NATIVE_KEYS if native_available() else KEYS
    assert all(data[k] > 0 for k in keys), {k: data.get(k) for k in keys}
    assert data["steps"] == 30 and data["vector_envs"] == 64
    assert data["ratio"] == pytest.approx(data["hexloading_steps_per_s"] / data["hopper_steps_per_s"])
    assert data["vector_ratio"] == pytest.approx(data["vector_steps_per_s"] / data["hopper_steps_per_s"])
    if data["vector_backend"] == "native":  # the batch: its physics alone is timed too
        assert data["vector_physics_bound_steps_per_s"] > 0
        assert data["vector_physics_share"] == pytest.approx(
            data["vector_steps_per_s"] / data["vector_physics_bound_steps_per_s"]
        )
    if native_available():
        cost = data["circuit_cost_us"]
        assert (
            cost["period"] > 0
            and cost["circuit"] > 0
            and cost["joints"] == pytest.approx(cost["period"] - cost["circuit"])
        )
        assert data["batch_speedup"] == pytest.approx(
            data["batch_realtime_factor_native"] / data["batch_realtime_factor_native_1thread"]
        )
        assert 0 < data["batch_cores_used"] <= data["batch_threads"] + 0.1
        assert data["batch_realtime_factor_per_core"] == pytest.approx(
            data["batch_realtime_factor_native"] / data["batch_cores_used"]
        )
    assert not list(tmp_path.glob(".*tmp*"))


def test_vector_rate_works_with_whatever_vector_env_is_registered():
    rate, kind = vector_steps_per_second(num_envs=2, vector_steps=3)
    assert rate > 0 and kind.endswith("VectorEnv")


@pytest.mark.skipif(not native_available(), reason="needs the native plugin")
def test_batch_rollouts_are_timed_and_checked():
    assert bench.batch_realtime_factor_native(nbatch=2, nthread=1, seconds=0.01) > 0
    with pytest.raises(ValueError, match="nbatch"):
        bench.batch_realtime_factor_native(nbatch=0)


def test_interleaved_rates_time_every_env_in_blocks(monkeypatch):
    from hexgym_lab import bench

    blocks = []
    timed = bench._timed_steps
    monkeypatch.setattr(bench, "_timed_steps", lambda env, actions: blocks.append(len(actions)) or timed(env, actions))
    rates = interleaved_steps_per_second({"a": ("Hopper-v5", {}), "b": ("HexLoading-v0", {})}, 7, rounds=3)
    assert set(rates) == {"a", "b"} and all(r > 0 for r in rates.values())
    assert blocks == [2, 2, 2, 2, 3, 3]  # a, b, a, b, a, b: the 7 steps of each in three blocks, in turn


def test_bad_step_count_is_refused():
    with pytest.raises(ValueError, match="steps"):
        steps_per_second("HexLoading-v0", 0)
    with pytest.raises(ValueError, match="num_envs"):
        vector_steps_per_second(num_envs=0)
    with pytest.raises(ValueError, match="rounds"):
        interleaved_steps_per_second({"a": ("Hopper-v5", {})}, 5, rounds=0)
