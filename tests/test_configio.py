"""Run configurations to and from JSON: round trip, overrides, and one-line errors for bad files."""

from __future__ import annotations

import dataclasses
import json

import pytest

from curbside.cli.localize import main
from curbside.errors import CurbsideInputError
from curbside.localize.filter import FilterConfig
from curbside.localize.runconfig import RunConfig


def test_every_parameter_round_trips_through_json():
    config = RunConfig.for_mode("paper", seed=7).with_overrides(
        {"filter.start.fix_heading_sigma_deg": 20, "engine.max_update_interval_s": "0.75"}
    )
    again = RunConfig.from_dict(json.loads(json.dumps(config.to_dict())))
    assert again == config
    assert again.filter.gnss.sigma_factor == 1.0 and again.filter.start.fix_heading_sigma_deg == 20.0
    assert RunConfig.from_dict({"unseen_velocity": {}}) == RunConfig()
    before_auto = RunConfig().with_overrides({"unseen_velocity.mode": "off"})
    assert RunConfig.from_dict({}) == before_auto  # a run.json from before the block replays as it ran
    stop28 = RunConfig().to_dict()
    for key in ("crossing_weight", "crossing_angle_deg"):
        del stop28["filter"]["map"][key]
    replayed = RunConfig.from_dict(stop28).filter.map  # one street weight, crossing or not, as it ran
    assert (replayed.crossing_weight, replayed.conflict_walkable_first) == (None, True)
    stop27 = json.loads(json.dumps(stop28))
    del stop27["filter"]["map"]["conflict_walkable_first"]
    replayed = RunConfig.from_dict(stop27).filter.map  # soft walls, buildings over sidewalks, as it ran
    assert (replayed.conflict_wall_tolerance_m, replayed.conflict_walkable_first) == (1.5, False)
    assert replayed.crossing_weight is None
    older = json.loads(json.dumps(stop27))
    for key in ("conflict_share_min", "conflict_wall_tolerance_m"):
        del older["filter"]["map"][key]
    replayed = RunConfig.from_dict(older).filter.map  # hard walls, as it ran
    assert (replayed.conflict_wall_tolerance_m, replayed.conflict_walkable_first) == (0.0, False)
    assert replayed.crossing_weight is None
    before_accuracy = RunConfig().to_dict()
    del before_accuracy["filter"]["gnss"]["correlation_accuracy_m"]
    assert RunConfig.from_dict(before_accuracy).filter.gnss.correlation_accuracy_m == 0.0  # as it ran
    by_hand = RunConfig.from_dict({"filter": {"gnss": {"sigma_factor": 1.0, "correlation_time_s": 5.0}}})
    assert by_hand.filter.gnss.correlation_accuracy_m == 10.0
    partial = RunConfig.from_dict({"filter": {"map": {"jaywalk_weight": 0.2}}}).filter.map  # by hand
    assert (partial.conflict_wall_tolerance_m, partial.conflict_walkable_first) == (1.5, True)
    assert partial.crossing_weight == FilterConfig().map.crossing_weight == 0.7
    before_street_heading = RunConfig().to_dict()  # 0.1 to stop 24: no street-heading part
    del before_street_heading["filter"]["street_heading"]
    assert RunConfig.from_dict(before_street_heading).filter.street_heading.strength_per_m == 0.0
    before_gate = RunConfig().to_dict()  # stops 25-30: the part, off or opted in, without the turn gate
    del before_gate["filter"]["street_heading"]["max_turn_deg"]
    assert RunConfig.from_dict(before_gate).filter.street_heading.max_turn_deg == 90.0
    hand_block = {"filter": {"street_heading": {"strength_per_m": 2.0}}}
    by_hand = RunConfig.from_dict(hand_block).filter.street_heading
    assert (by_hand.strength_per_m, by_hand.max_turn_deg) == (2.0, 30.0)
    by_hand_filter = RunConfig.from_dict({"filter": {"n_particles": 500}}).filter
    assert by_hand_filter.street_heading == FilterConfig().street_heading
    before_turn = RunConfig().to_dict()  # 0.1 to stop 35: no heading correction from the fixes
    del before_turn["filter"]["heading_correction"]
    assert RunConfig.from_dict(before_turn).filter.heading_correction.fraction == 0.0
    assert by_hand_filter.heading_correction == FilterConfig().heading_correction


def test_the_paper_preset_is_the_plain_filter():
    paper = FilterConfig.preset("paper")
    assert (paper.gnss.outlier_prob, paper.gnss.correlation_time_s, paper.recovery.max_fraction) == (0, 0, 0)
    assert paper.heading_correction.fraction == 0.0
    assert paper.gnss.sigma_factor == 1.0 and paper.map.conflict_wall_tolerance_m == 0.0  # hard walls always
    assert paper.map == dataclasses.replace(
        FilterConfig().map, conflict_wall_tolerance_m=0.0, conflict_walkable_first=False, crossing_weight=None
    )
    assert (paper.n_particles, FilterConfig().n_particles) == (500, 2000)
    with pytest.raises(ValueError):
        FilterConfig.preset("best")


@pytest.mark.parametrize(
    "data, words",
    [
        ({"filter": {"gnss": {"sigma": 1.0}}}, ["unknown parameter", "sigma"]),
        ({"seed": "seven"}, ["seed", "integer"]),
        ({"filter": {"n_particles": 0}}, ["n_particles"]),
        ({"filter": {"street_heading": {"max_turn_deg": 120}}}, ["max_turn_deg", "(0, 90]"]),
        ({"mode": "best"}, ["mode"]),
        ({"filter": {"map": {"jaywalk_weight": True}}}, ["jaywalk_weight", "number"]),
    ],
)
def test_bad_configs_are_one_line_input_errors(data, words):
    with pytest.raises(CurbsideInputError) as info:
        RunConfig.from_dict(data)
    message = str(info.value)
    assert "\n" not in message and all(w in message for w in words)


def test_bad_overrides_name_the_parameter():
    with pytest.raises(CurbsideInputError, match="no parameter 'sigma'"):
        RunConfig().with_overrides({"filter.gnss.sigma": 1})
    with pytest.raises(CurbsideInputError, match="no section 'gps'"):
        RunConfig().with_overrides({"filter.gps.sigma_factor": 1})


@pytest.mark.parametrize("content", ["{not json", '{"mode": "fused"}', '{"config": {"seed": "x"}}'])
def test_localize_run_with_a_bad_run_json_exits_2(tmp_path, capsys, content):
    bad = tmp_path / "run.json"
    bad.write_text(content)
    assert main(["run", "--config", str(bad), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "run.json" in err and not (tmp_path / "out").exists()
