"""The swing-alone replay (``python -m hexgym.tools.swing_replay``): a table set's swing model against the
reference's swing with the other joints replayed."""

import numpy as np
import pytest

from hexgym.hydraulics.reference import ReferenceModel
from hexgym.mbl.table import load_tables
from hexgym.model.commandlog import CommandLog
from hexgym.model.replay import replay
from hexgym.tools import swing_replay
from hexgym.tools.scenarios import POSE_CYCLE


@pytest.fixture(scope="module")
def swing_rows() -> np.ndarray:
    t = np.round(np.arange(0.0, 6.0 + 1e-9, 0.05), 10)
    spools = np.zeros((len(t), 4))
    spools[(t >= 0.5) & (t < 3.5), 0] = 11.0  # a full swing from rest, then braked by the crossover reliefs
    return replay(ReferenceModel(), CommandLog(t, spools), start=POSE_CYCLE, dt_out=swing_replay.ROW_S)


def test_each_swing_model_follows_a_full_swing_and_its_braking(swing_rows):
    tables = {name: load_tables(table_set=name) for name in ("paper", "extended")}
    assert np.ptp(swing_rows["q_swing"]) > 3.0  # the reference turned half a turn
    for model in swing_replay.MODELS:
        errors = swing_replay.swing_errors(swing_rows, model, tables)
        assert errors[0] == 0.0 and np.all(np.isfinite(errors))
        assert errors.mean() < 0.4, model  # metres at the tip, against a turn of 3.2 rad at 4.3 m (13 m)


def test_the_command_line_refuses_a_bad_log_count(capsys):
    with pytest.raises(SystemExit):
        swing_replay.main(["--logs", "0"])
    assert "--logs" in capsys.readouterr().err
