"""Learning curves: reading a run's curve.csv, smoothing, the summary over seeds, the figure and the command."""

import json
import math

import numpy as np
import pytest

from hexgym_lab.agents.curves import CURVE_FILE, on_steps, read_curve, smoothed, summarise
from hexgym_lab.agents.training import CURVE_COLUMNS
from hexgym_lab.cli import main


def _run(directory, rows):
    directory.mkdir(parents=True)
    lines = [",".join(CURVE_COLUMNS)] + [",".join(str(v) for v in row) for row in rows]
    (directory / CURVE_FILE).write_text("\n".join(lines) + "\n")
    return directory


def _learning(directory, reach_at):
    """A run whose success rate climbs from 0 to 1 by ``reach_at`` rollouts of 1,000 steps (of 12)."""
    rows = [(1000 * (i + 1), i, 10, -3 + i, min(1.0, i / reach_at), "") for i in range(12)]
    return _run(directory, rows)


def test_smoothing_and_common_steps():
    values = np.array([math.nan, 1.0, 3.0, math.nan, 5.0])
    np.testing.assert_allclose(smoothed(values, 2), [math.nan, 1.0, 2.0, 3.0, 5.0])
    curve = {"steps": np.array([100.0, 200.0]), "x": np.array([1.0, 3.0])}
    np.testing.assert_allclose(on_steps(curve, "x", np.array([50, 100, 150, 250])), [math.nan, 1, 1, 2])


def test_summary_over_seeds(tmp_path):
    curves = {name: read_curve(_learning(tmp_path / name, reach)) for name, reach in (("a", 4), ("b", 8), ("c", 50))}
    summary = summarise(curves, 0.9)
    runs = summary["runs"]
    assert runs["a"]["steps"] == 12000 and runs["a"]["final_success_rate"] == pytest.approx(1.0)
    assert runs["a"]["steps_to_success_0.9"] < runs["b"]["steps_to_success_0.9"]
    assert runs["c"]["steps_to_success_0.9"] is None and summary["runs_reaching_success_level"] == 2


def test_the_command_writes_figure_and_summary(tmp_path, capsys):
    runs = [str(_learning(tmp_path / f"s{k}", 3 + k)) for k in range(3)]
    out, summary = tmp_path / "curves.png", tmp_path / "curves.json"
    assert main(["curves", *runs, "--out", str(out), "--json", str(summary), "--title", "three seeds"]) == 0
    assert out.stat().st_size > 10_000 and json.loads(summary.read_text())["runs_reaching_success_level"] == 3


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (None, "no learning curve"),
        ("a,b\n1,2\n", "not a learning curve"),
        (",".join(CURVE_COLUMNS) + "\n", "no rollout recorded"),
        (",".join(CURVE_COLUMNS) + "\n1,x,1,1,1,\n", "not numbers"),
        (",".join(CURVE_COLUMNS) + "\n2,1,1,1,1,\n1,1,1,1,1,\n", "increasing steps"),
    ],
)
def test_bad_curves_are_named(tmp_path, capsys, text, message):
    run = tmp_path / "run"
    run.mkdir()
    if text is not None:
        (run / CURVE_FILE).write_text(text)
    with pytest.raises(ValueError, match=message):
        read_curve(run)
    assert main(["curves", str(run), "--out", str(tmp_path / "c.png")]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
