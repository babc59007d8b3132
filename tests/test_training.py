"""hexgym train and clone: rl-zoo3 hyperparameters, short runs that save, reload and resume."""

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from hexgym.agents.policies import load_trained
from hexgym.agents.policy_files import normalizer_path
from hexgym_lab.agents.curves import read_curve
from hexgym_lab.agents.hyperparams import HYPERPARAMS_DIR, algo_kwargs, load_hyperparams
from hexgym_lab.agents.training import check_hyperparams, clone_scripted, latest_checkpoint, make_env, train

# a tiny PPO on 8 s episodes, so a run of a few hundred steps takes seconds
TINY = {
    "HexLoading-v0": {
        "n_timesteps": 256,
        "policy": "MlpPolicy",
        "normalize": "dict(norm_obs=True, norm_reward=False)",
        "n_steps": 64,
        "batch_size": 64,
        "n_epochs": 2,
        "gamma": 0.995,
        "policy_kwargs": "dict(log_std_init=-1.0, net_arch=dict(pi=[32, 32], vf=[32, 32]))",
        "env_kwargs": {"time_limit": 8.0},
    }
}


@pytest.fixture
def tiny_yaml(tmp_path):
    path = tmp_path / "tiny.yml"
    path.write_text(yaml.safe_dump(TINY))
    return path


def test_shipped_hyperparameters_are_rl_zoo_format():
    for algo in ("ppo", "sac"):
        hp = load_hyperparams(algo)
        assert hp["policy"] == "MlpPolicy" and hp["normalize"]["norm_obs"] is True
        kwargs = algo_kwargs(hp)
        assert "n_timesteps" not in kwargs and "normalize" not in kwargs and "policy_kwargs" in kwargs
        assert (HYPERPARAMS_DIR / f"{algo}.yml").is_file()
    assert load_hyperparams("ppo")["policy_kwargs"]["net_arch"]["pi"] == [256, 256]


def test_the_from_scratch_hyperparameters_make_their_curriculum_environment():
    hp = load_hyperparams("ppo", path=HYPERPARAMS_DIR / "ppo_scratch.yml")
    check_hyperparams("ppo", hp)
    assert hp["n_envs"] == 16 and algo_kwargs(hp)["n_steps"] * hp["n_envs"] == 4096
    env = make_env(**hp["env_kwargs"])
    starts = [env.reset(seed=seed)[1]["bucket_kg"] > 0 for seed in range(20)]
    assert 3 <= sum(starts) <= 14  # two fifths of the episodes start loaded
    env.close()


def test_hyperparameter_errors(tmp_path, tiny_yaml):
    with pytest.raises(ValueError, match="algo"):
        load_hyperparams("dqn")
    with pytest.raises(FileNotFoundError, match="no hyperparameter file"):
        load_hyperparams("ppo", path=tmp_path / "none.yml")
    with pytest.raises(ValueError, match="no entry for 'Other-v0'"):
        load_hyperparams("ppo", "Other-v0", path=tiny_yaml)


def test_short_ppo_run_saves_reloads_and_resumes(tmp_path, tiny_yaml, capsys, monkeypatch):
    monkeypatch.setenv("HEXGYM_PROGRESS", "lines")  # the rollout lines show where progress does (standard error)
    path = train("ppo", timesteps=256, seed=0, log_dir=tmp_path, hyperparams=tiny_yaml, n_envs=2,
                 checkpoint_every=128, progress_bar=False)  # fmt: skip
    assert path.is_file() and normalizer_path(path).is_file()
    checkpoint = latest_checkpoint(path.parent)
    assert checkpoint is not None and checkpoint.name == "rl_model_256_steps.zip"
    assert normalizer_path(checkpoint).is_file()
    for saved in (path, checkpoint):  # what it was trained on, for loading to check
        recorded = json.loads(normalizer_path(saved).read_text())["trained_on"]
        assert recorded["env_id"] == "HexLoading-v0" and recorded["tables"] == "circuit"
        assert len(recorded["obs_names"]) == 23 and recorded["obs_names"][0] == "boom_angle"
    policy = load_trained(path)
    assert policy.normalizer is not None and policy.normalizer.obs_count > 256  # it saw the rollouts
    action = policy.act(np.zeros(23, np.float32), None)
    assert action.shape == (4,) and np.all(np.abs(action) <= 1.0)
    # the same command with a larger budget continues from the checkpoint
    train("ppo", timesteps=384, seed=0, log_dir=tmp_path, hyperparams=tiny_yaml, n_envs=2,
          checkpoint_every=128, progress_bar=False)  # fmt: skip
    captured = capsys.readouterr()
    assert "resuming from" in captured.out
    assert load_trained(path).model.num_timesteps >= 384
    # a line per rollout of 2 envs x 64 steps (two in the first run, one resumed): steps so far, tonnes
    # delivered, episodes ended and their return, the rate
    lines = [line for line in captured.err.splitlines() if "| rollout:" in line]
    assert not [line for line in captured.out.splitlines() if "| rollout:" in line]
    assert [line.split()[0] for line in lines] == ["128", "256", "384"]
    assert all("t delivered" in line and "steps/s" in line for line in lines)
    assert "2 episodes ended, mean return" in lines[1]  # each env's 8 s episode ends at its step 80
    # the same rollouts as the run's learning curve, the resumed one appended
    curve = read_curve(path.parent)
    assert curve["steps"].tolist() == [128, 256, 384] and curve["episodes"].tolist() == [0, 2, 0]
    assert np.isnan(curve["mean_return"][0]) and np.isfinite(curve["mean_return"][1])
    assert np.all(curve["delivered_t"] >= 0) and np.isnan(curve["success_rate"]).all()  # no success criterion


def test_a_fine_tune_keeps_its_starting_observation_statistics(tmp_path, tiny_yaml):
    """``init_from``: the policy goes on learning on the inputs it was fitted to (a from-scratch run updates
    them, as the test above checks)."""
    start = train("ppo", timesteps=128, seed=0, log_dir=tmp_path / "start", hyperparams=tiny_yaml, n_envs=2,
                  checkpoint_every=128, progress_bar=False, report=False)  # fmt: skip
    tuned = train("ppo", timesteps=128, seed=1, log_dir=tmp_path / "tuned", hyperparams=tiny_yaml, n_envs=2,
                  init_from=start, checkpoint_every=128, progress_bar=False, report=False)  # fmt: skip
    before, after = load_trained(start).normalizer, load_trained(tuned).normalizer
    assert after.obs_count == before.obs_count
    np.testing.assert_array_equal(after.obs_mean, before.obs_mean)
    assert load_trained(tuned).model.num_timesteps >= 128


def test_a_fine_tune_learns_and_explores_with_its_own_hyperparameters(tmp_path, tiny_yaml):
    """``init_from`` with another YAML: its learning rate, rollout and exploration noise, not the start's."""
    start = train("ppo", timesteps=128, seed=0, log_dir=tmp_path / "start", hyperparams=tiny_yaml, n_envs=2,
                  checkpoint_every=128, progress_bar=False, report=False)  # fmt: skip
    careful = yaml.safe_load(tiny_yaml.read_text())
    entry = careful["HexLoading-v0"]
    entry.update(learning_rate=1e-6, n_steps=32, policy_kwargs=entry["policy_kwargs"].replace("log_std_init=-1.0",
                 "log_std_init=-2.5"))  # fmt: skip
    (tmp_path / "careful.yml").write_text(yaml.safe_dump(careful))
    tuned = train("ppo", timesteps=64, seed=1, log_dir=tmp_path / "tuned", hyperparams=tmp_path / "careful.yml",
                  n_envs=2, init_from=start, checkpoint_every=64, progress_bar=False, report=False)  # fmt: skip
    model = load_trained(tuned).model
    assert model.learning_rate == 1e-6 and model.n_steps == 32
    assert load_trained(start).model.learning_rate != 1e-6
    np.testing.assert_allclose(model.policy.log_std.detach().numpy(), -2.5, atol=1e-3)  # barely moved at 1e-6


def _interrupt() -> None:
    raise KeyboardInterrupt  # Ctrl-C


def _terminate() -> None:
    import os
    import signal

    os.kill(os.getpid(), signal.SIGTERM)  # ``kill``, a batch scheduler's stop


@pytest.mark.parametrize("stop", [_interrupt, _terminate], ids=["ctrl-c", "sigterm"])
def test_a_stopped_run_leaves_a_usable_model(tmp_path, tiny_yaml, monkeypatch, capsys, stop):
    import signal

    from stable_baselines3.common.callbacks import BaseCallback, CallbackList

    from hexgym_lab.agents import training

    class StopAfter(BaseCallback):  # stopped after 200 steps
        def _on_step(self) -> bool:
            if self.num_timesteps >= 200:
                stop()
            return True

    report = training._rollout_report_callback  # still writes the curve
    monkeypatch.setattr(training, "_rollout_report_callback", lambda *args: CallbackList([report(*args), StopAfter()]))
    before = signal.getsignal(signal.SIGTERM)  # another test's library (Ray) may have set its own
    with pytest.raises(KeyboardInterrupt):
        train("ppo", timesteps=100_000, seed=0, log_dir=tmp_path, hyperparams=tiny_yaml, n_envs=2,
              checkpoint_every=128, progress_bar=False)  # fmt: skip
    run_dir = tmp_path / "ppo_HexLoading-v0"
    path = run_dir / "model.zip"
    policy = load_trained(path)
    assert 200 <= policy.model.num_timesteps < 300 and normalizer_path(path).is_file()
    assert signal.getsignal(signal.SIGTERM) is before  # the handler is put back
    # it says where what it kept lies: the model and its normaliser, the last checkpoint and its, the curve
    checkpoint = training.latest_checkpoint(run_dir)
    assert checkpoint is not None and normalizer_path(checkpoint).is_file()
    said = capsys.readouterr().out
    for kept in (path, normalizer_path(path), checkpoint, normalizer_path(checkpoint), run_dir / "curve.csv"):
        assert str(kept) in said


@pytest.mark.slow  # ~40-75 s on 2 cores: two rounds of spawned recording workers
def test_behaviour_cloning_fits_the_scripted_loader(tmp_path, tiny_yaml):
    out = clone_scripted(tmp_path / "bc.zip", episodes=2, dagger_rounds=1, dagger_episodes=1, epochs=300,
                         hyperparams=tiny_yaml, log=lambda _: None)  # fmt: skip
    policy = load_trained(out)
    from hexgym_lab.agents.training import record_episode

    demos = record_episode(seed=1000, gamma=0.99, env_kwargs={"time_limit": 8.0})  # a training episode
    predicted = np.array([policy.act(o, None) for o in demos.obs])
    # the clone is closer to the loader than always answering the loader's average action
    assert np.mean((predicted - demos.actions) ** 2) < 0.7 * np.mean((demos.actions - demos.actions.mean(0)) ** 2)


def test_previous_action_wrapper_appends_the_executed_action():
    from hexgym_lab.agents.training import make_env

    env = make_env("HexLoading-v0", "hexgym.wrappers.PreviousActionWrapper", time_limit=2.0)
    obs, _ = env.reset(seed=0)
    assert obs.shape == (27,) == env.observation_space.shape and np.all(obs[23:] == 0.0)
    obs, *_ = env.step(np.array([2.0, 0.5, -0.5, 0.0], np.float32))
    assert np.allclose(obs[23:], [1.0, 0.5, -0.5, 0.0])  # clipped, as the environment applies it
    assert env.observation_space.contains(obs)
    with pytest.raises(ValueError, match="env_wrapper"):
        make_env("HexLoading-v0", "hexgym.nowhere.Wrapper")


def test_demonstrations_are_labelled_by_the_state_derived_loader():
    from hexgym.agents.scripted import ScriptedLoader
    from hexgym_lab.agents.training import make_env, record_episode

    demos = record_episode(seed=5, gamma=0.99, env_kwargs={"time_limit": 3.0}, noise=0.3)
    assert demos.obs.shape == (30, 23) and demos.actions.shape == (30, 4) and demos.returns.shape == (30,)
    assert np.all(np.abs(demos.actions) <= 1.0)
    # the first state is the reset's: its label is the loader's action there, noise or not
    env = make_env("HexLoading-v0", time_limit=3.0)
    obs, _ = env.reset(seed=5)
    assert np.array_equal(obs, demos.obs[0])
    assert np.array_equal(ScriptedLoader().label(env.unwrapped), demos.actions[0])


def test_cloning_runs_its_episodes_on_the_tables_asked_for(tmp_path, tiny_yaml, monkeypatch):
    """``tables`` reaches every recorded and scored episode's environment (through the hyperparameters'
    env_kwargs), after the environment has accepted it."""
    import contextlib

    import hexgym_lab.agents.training as training

    seen = {}
    monkeypatch.setattr(training, "_worker_pool", contextlib.nullcontext)
    monkeypatch.setattr(training, "_clone_rounds", lambda out, rounds, hp, *rest: seen.setdefault("hp", hp) and out)
    clone_scripted(tmp_path / "bc.zip", hyperparams=tiny_yaml, tables="circuit", log=lambda _: None)
    assert seen["hp"]["env_kwargs"]["tables"] == "circuit"
    with pytest.raises(ValueError, match="tables"):
        clone_scripted(tmp_path / "bc2.zip", hyperparams=tiny_yaml, tables="nope", log=lambda _: None)


def test_select_keeps_the_checkpoint_that_loads_most_on_the_selection_seeds(tmp_path, tiny_yaml):
    from hexgym_lab.agents.select import select_checkpoint
    from hexgym_lab.agents.training import checkpoints

    path = train("ppo", timesteps=256, seed=0, log_dir=tmp_path, hyperparams=tiny_yaml, n_envs=2,
                 checkpoint_every=128, progress_bar=False, report=False)  # fmt: skip
    directory = path.parent / "checkpoints"
    assert [(n, p.name) for n, p in checkpoints(directory)] == [(128, "rl_model_128_steps.zip"),
                                                                (256, "rl_model_256_steps.zip")]  # fmt: skip
    out = tmp_path / "kept" / "agent.zip"
    rows = select_checkpoint(directory, out, seed_sets=[(3, 1)])
    kept = [row for row in rows if row["selected"]]
    assert [row["steps"] for row in rows] == [128, 256] and len(kept) == 1
    assert kept[0]["mean_tonnes_per_hour"] == max(row["mean_tonnes_per_hour"] for row in rows)
    source = Path(kept[0]["checkpoint"])
    assert out.read_bytes() == source.read_bytes()
    assert normalizer_path(out).read_bytes() == normalizer_path(source).read_bytes()
    with pytest.raises(ValueError, match="no checkpoints"):
        select_checkpoint(tmp_path / "kept", tmp_path / "other.zip")
