"""`hexgym bench`: HexLoading-v0 and Hopper-v5 steps per second in one process."""

import json

import pytest

from hexgym.bench import steps_per_second
from hexgym.cli import main


def test_bench_command_prints_and_writes_consistent_json(tmp_path, capsys):
    out = tmp_path / "bench.json"
    assert main(["bench", "--steps", "30", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "HexLoading-v0" in printed and "Hopper-v5" in printed and "ratio" in printed
    data = json.loads(out.read_text())
    assert data["steps"] == 30 and data["hexloading_steps_per_s"] > 0 and data["hopper_steps_per_s"] > 0
    assert data["ratio"] == pytest.approx(data["hexloading_steps_per_s"] / data["hopper_steps_per_s"])
    assert not list(tmp_path.glob(".*tmp*"))


def test_bad_step_count_is_refused():
    with pytest.raises(ValueError, match="steps"):
        steps_per_second("HexLoading-v0", 0)
