"""RLlib's PPO on HexLoading-v0 (:mod:`hexgym_lab.agents.rllib`): one small iteration on a local Ray, a
checkpoint that resumes and that ``hexgym evaluate`` accepts. Skipped without Ray."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

pytest.importorskip("ray.rllib")
pytest.importorskip("torch")

# one iteration of 200 steps (episodes of 10 s = 100 steps), a small network, one pass
SMALL = """
HexLoading-v0:
  n_envs: 1
  n_steps: 200
  batch_size: 100
  n_epochs: 1
  gamma: 0.995
  learning_rate: !!float 1e-4
  clip_range: 0.1
  env_kwargs: {time_limit: 10.0}
  policy_kwargs: "dict(net_arch=dict(pi=[32, 32], vf=[32, 32]))"
"""


def test_rllib_ppo_trains_resumes_and_evaluates(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    import ray

    from hexgym_lab.cli import main

    (tmp_path / "ppo.yml").write_text(SMALL)
    train = ["train", "--framework", "rllib", "--algo", "ppo", "-f", str(tmp_path / "logs"),
             "--hyperparams", str(tmp_path / "ppo.yml"), "--num-env-runners", "1", "--ray"]  # fmt: skip
    assert main([*train, "--timesteps", "200"]) == 0
    out = capsys.readouterr().out
    assert "iteration 1: 200 steps" in out
    checkpoint = tmp_path / "logs" / "rllib_ppo_HexLoading-v0" / "checkpoint"
    assert (checkpoint / "rllib_checkpoint.json").is_file()
    assert not ray.is_initialized()  # the Ray it started is shut down

    assert main([*train, "--timesteps", "400"]) == 0  # resumes: one more iteration, not two
    out = capsys.readouterr().out
    assert "resuming from" in out and "(200 steps done)" in out and "iteration 2: 400 steps" in out
    assert "iteration 3" not in out

    report = tmp_path / "eval.json"
    assert (
        main(["evaluate", "--policy", str(checkpoint), "--episodes", "1", "--seconds", "3", "--json", str(report)]) == 0
    )
    result = json.loads(report.read_text())
    assert result["episodes"] == 1 and result["per_episode"][0]["sim_seconds"] == pytest.approx(3.0, abs=0.11)


def test_rllib_refuses_what_it_does_not_do(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    from hexgym_lab.cli import main

    assert main(["train", "--framework", "rllib", "--algo", "sac", "-f", str(tmp_path)]) == 2
    assert "trains ppo only" in capsys.readouterr().err
    assert main(["train", "--ray", "-f", str(tmp_path)]) == 2
    assert "--framework rllib" in capsys.readouterr().err
    assert main(["evaluate", "--policy", str(tmp_path), "--episodes", "1"]) == 2  # a directory, no checkpoint
    assert "not an RLlib checkpoint" in capsys.readouterr().err
    assert main(["train", "--framework", "rllib", "--num-env-runners", "64", "--ray", "-f", str(tmp_path)]) == 2
    assert "--num-env-runners 64 needs 64 cores" in capsys.readouterr().err
