"""The reference model against the machine's published behaviour (slow: ~30 s of simulation)."""

import json

import pytest

from hexgym_lab.reference_report import run_report


@pytest.mark.slow
def test_reference_report_on_the_papers_valve(tmp_path):
    summary = run_report(tmp_path, valve="paper")
    assert json.loads((tmp_path / "summary.json").read_text()) == summary
    assert (tmp_path / "interactions.png").stat().st_size > 20_000
    single, inter = summary["single_function"], summary["interactions"]
    assert 10.3 < single["swing_rpm"] < 11.7  # Cat 320/325F: 11.2-11.3 rpm
    assert single["boom_up_mps"] == pytest.approx(0.144, rel=0.05)  # one pump's flow / boom head area
    assert single["bucket_curl_mps"] == pytest.approx(0.289, rel=0.05)
    assert 30 < single["idle_flow_l_per_min"] < 46  # 10-20 % of 230 L/min
    # Test 1: the heavier boom gets little flow until the bucket stops (paper Figs 5-6)
    assert inter["test1_boom_mps_while_bucket_moves"] < 0.2 * inter["test1_boom_mps_alone_same_time"]
    # Test 2: the swing is slowed while the stick moves (Figs 7-8)
    assert inter["test2_swing_rad_s_while_stick_moves"] < 0.5 * inter["test2_swing_rad_s_alone_same_time"]


@pytest.mark.slow
def test_the_cat_valve_against_the_published_figures(tmp_path):
    """Both pumps on boom and stick, priorities and regeneration against the Cat 323F's cylinder times, in the
    service manual's poses: every figure within +-20 %; the boom raise, from the bucket on the ground, no faster than
    both pumps' flow can fill the boom cylinders over that stroke."""
    from hexgym.hydraulics.reference import ReferenceModel
    from hexgym.machine import kinematics
    from hexgym.machine import parameters as p
    from hexgym_lab.published_figures import boom_on_ground

    summary = run_report(tmp_path)
    figures = summary["published_figures"]
    assert figures["valve"] == "cat"
    assert all(row["within"] for row in figures["cylinder_times_s"].values())
    assert all(row["within"] for row in figures["swing"].values())
    assert all(row["within"] for row in figures["relief_settings_mpa"].values())
    boom = p.BOOM_CYLINDER
    start = kinematics.cylinder_length("boom", boom_on_ground(ReferenceModel())) - boom.retracted_length
    assert 0.3 * boom.stroke < start < 0.7 * boom.stroke  # the bucket reaches the ground with the boom part raised
    flow_bound = boom.head_area * (boom.stroke - p.STROKE_END_MARGIN - start) / (2 * p.PUMP_MAX_FLOW)
    # slower than the flow bound by what the pumps' shared power limit takes at the boom's pressure
    assert flow_bound < figures["cylinder_times_s"]["boom_raise"]["model"] < 1.5 * flow_bound
    inter = summary["interactions"]
    one_pump_boom = p.PUMP_MAX_FLOW / boom.head_area  # both cylinders' area
    assert inter["test3_boom_mps_with_stick_in"] > 0.75 * one_pump_boom  # boom priority keeps pump 1 for it
    assert inter["test3_stick_mps_with_boom_up"] > 0.3  # the stick on pump 2 and its regeneration
    assert inter["test1_boom_mps_while_bucket_moves"] > 0.5 * inter["test1_boom_mps_alone_same_time"]  # boom 2
