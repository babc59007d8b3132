"""hexgym evaluate and video: figures from the info stream, the policy sources, clear errors."""

import json

import numpy as np
import pytest

from hexgym.agents.policies import SHIPPED_POLICY, load_policy
from hexgym.agents.policy_files import normalizer_path
from hexgym_lab import cli
from hexgym_lab.agents.evaluate import (
    FULL_ENOUGH_KG,
    METRIC_KEYS,
    Episode,
    aggregate,
    evaluate,
    tonnes_per_hour_interval,
)


def _episode(deliveries: dict[float, float], seconds: float = 60.0, seed: int = 0) -> Episode:
    """An episode whose truck gains ``kg`` at each time ``t`` of ``deliveries``."""
    e = Episode(seed=seed)
    truck = 0.0
    for t in np.arange(1, int(seconds * 10) + 1) / 10:
        truck += deliveries.get(round(float(t), 1), 0.0)
        e.time_s.append(float(t))
        e.truck_kg.append(truck)
    e.fuel_l, e.spilled_kg = 1.0, 100.0
    return e


def test_dumps_merge_close_deliveries_and_cycles_count_full_ones():
    full = FULL_ENOUGH_KG
    e = _episode({10.0: full / 2, 10.5: full / 2, 30.0: 200.0, 40.0: full, 52.0: full})
    assert [round(kg) for _, kg in e.dumps()] == [round(full), 200, round(full), round(full)]
    s = e.summary()
    assert s["full_dumps"] == 3
    assert s["cycle_intervals_s"] == pytest.approx([30.0, 12.0])


def test_aggregate_pools_the_episodes():
    full = FULL_ENOUGH_KG
    result = aggregate([_episode({10.0: full, 30.0: full}), _episode({20.0: 300.0})])
    assert result["success_rate"] == 0.5  # the second episode never delivered a full-enough bucket
    delivered_t = (2 * full + 300.0) / 1000
    assert result["delivered_t_per_episode"] == pytest.approx(delivered_t / 2)
    assert result["tonnes_per_hour"] == pytest.approx(delivered_t / (120 / 3600))
    assert result["mean_cycle_time_s"] == pytest.approx(20.0)
    assert result["fuel_l_per_tonne"] == pytest.approx(2.0 / delivered_t)
    assert result["spilled_fraction"] == pytest.approx(0.2 / (0.2 + delivered_t))


def test_the_t_per_h_interval_covers_the_pooled_figure_and_narrows_with_episodes():
    rng = np.random.default_rng(0)
    delivered, seconds = rng.uniform(9.0, 13.0, 80), rng.uniform(120.0, 180.0, 80)
    wide, narrow = tonnes_per_hour_interval(delivered[:8], seconds[:8]), tonnes_per_hour_interval(delivered, seconds)
    assert wide[0] < delivered[:8].sum() / seconds[:8].sum() * 3600 < wide[1]
    assert narrow[1] - narrow[0] < 0.6 * (wide[1] - wide[0])  # ~1/sqrt(n): a tenth as many episodes, ~3x as wide
    assert tonnes_per_hour_interval(delivered[:1], seconds[:1]) is None  # one episode: no spread to resample
    assert tonnes_per_hour_interval(delivered, seconds) == narrow  # reproducible
    assert aggregate([_episode({10.0: 2000.0})])["tonnes_per_hour_ci95"] is None


def test_scripted_evaluation_json_has_the_keys(tmp_path):
    out = tmp_path / "eval.json"
    result = evaluate("scripted", episodes=1, seed=0, env_kwargs={"time_limit": 40.0}, json_out=str(out))
    written = json.loads(out.read_text())
    for key in METRIC_KEYS:
        assert key in written and key in result
    assert written["episodes"] == 1
    assert 0.0 <= written["success_rate"] <= 1.0
    # the scripted loader dumps its first bucket within ~25 s
    assert written["delivered_t_per_episode"] > 0.5


def test_bad_inputs_give_clear_errors(tmp_path, capsys):
    with pytest.raises(ValueError, match="episodes"):
        evaluate("scripted", episodes=0)
    with pytest.raises(FileNotFoundError, match="no policy file"):
        load_policy(str(tmp_path / "missing.zip"))
    not_a_zip = tmp_path / "model.zip"
    not_a_zip.write_text("hello")
    with pytest.raises(ValueError, match="not a Stable-Baselines3 model"):
        load_policy(str(not_a_zip))
    assert cli.main(["evaluate", "--policy", str(tmp_path / "nope.zip"), "--episodes", "1"]) == 2
    assert "no policy file" in capsys.readouterr().err


def test_normalizer_path_names():
    assert normalizer_path("run/model.zip").name == "model_vecnormalize.json"
    assert normalizer_path("ckpt/rl_model_2000_steps.zip").name == "rl_model_vecnormalize_2000_steps.json"


@pytest.mark.skipif(not SHIPPED_POLICY.is_file(), reason="no shipped policy in this checkout")
def test_shipped_policy_loads_and_acts():
    import gymnasium as gym

    policy = load_policy("shipped")
    env = gym.make("HexLoading-v0", time_limit=5.0)
    obs, _ = env.reset(seed=0)
    actions = []
    for _ in range(20):
        action = policy.act(obs, env.unwrapped)
        assert action.shape == (4,) and np.all(np.abs(action) <= 1.0)
        actions.append(action)
        obs, *_ = env.step(action)
    env.close()
    assert np.ptp(np.array(actions), axis=0).max() > 0.05  # it reacts to the state, not a constant


def test_video_writes_an_mp4_with_overlay(tmp_path, monkeypatch):
    from hexgym_lab.agents.film import overlay_text
    from hexgym_lab.agents.video import record_video

    frame = np.full((60, 200, 3), 100, np.uint8)
    marked = overlay_text(frame, "t 1.0 s")
    assert marked.shape == frame.shape and not np.array_equal(marked[:20], frame[:20])
    assert np.array_equal(marked[40:], frame[40:])  # only the strip at the top changes
    seen = []

    class BudgetSpy:  # what a policy sees: the episode's time left (observation 21)
        def reset(self) -> None:
            pass

        def act(self, obs, env):
            seen.append(float(obs[21]))
            return np.zeros(4, np.float32)

    monkeypatch.setattr("hexgym_lab.agents.video.load_policy", lambda spec, env_id, env_kwargs=None: BudgetSpy())
    result = record_video("scripted", tmp_path / "v.mp4", seconds=1.0, width=160, height=96)
    assert result["frames"] == 11 and result["video"].stat().st_size > 1000
    # a 1 s film of an episode that keeps its 180 s budget: the policy acts as it would in evaluation
    assert len(seen) == 10 and seen[-1] == pytest.approx(1.0 - 0.9 / 180.0, abs=1e-6)
    with pytest.raises(ValueError, match="camera"):
        record_video("scripted", tmp_path / "v.mp4", camera="drone")
