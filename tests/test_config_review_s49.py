"""Review s49 of the run and map configurations: what could never fit in memory, options that a
simulation would ignore, the fixes' lag bounds, and refusals that name the parameter at fault."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from serve_fixtures import TRIAL

from curbside import configio
from curbside.cli.localize import main
from curbside.cli.osmseg import main as osmseg_main
from curbside.configio import parameters, require, with_overrides
from curbside.errors import CurbsideInputError
from curbside.localize.filter.calibration import CalibrationConfig
from curbside.localize.raster import rasterize_map
from curbside.localize.ronin.stream import RoninStreamConfig
from curbside.localize.runconfig import FixLagConfig, RunConfig
from curbside.localize.steps import StepConfig
from curbside.osmseg.config import SegmentationConfig
from curbside.osmseg.mapio import read_map

DATA = Path(__file__).parent / "data"
MAP = DATA / "evaluate" / "sf-path3.geojson"  # the benchmark's path 3, about 280 x 230 m
SMALL_OSM = DATA / "osm" / "crossroads-mapped-sidewalks.osm"  # a crossroads ~300 m from path 1's start
GIB = 2**30


@pytest.fixture
def machine_of_16_gib(monkeypatch):
    """The memory checks see a machine of 16 GiB, whatever this one has."""
    monkeypatch.setattr(configio, "physical_memory_bytes", lambda: 16 * GIB)


def _refused(capsys, argv: list[str], prog=main) -> str:
    assert prog(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    return err


# -- 1. what could never fit in memory is refused up front ----------------------------------------------


def test_particles_beyond_the_machines_memory_are_refused_before_the_run(machine_of_16_gib, tmp_path,
                                                                         capsys):
    out = tmp_path / "run"
    err = _refused(capsys, ["run", TRIAL, "--particles", "1000000000", "-o", str(out)])
    assert err == (
        "localize: error: config: filter.n_particles (--particles) 1000000000: the particle arrays would "
        "need about 149 GiB, more than the 16 GiB of memory this machine has\n"
    )
    assert not out.exists()


def test_the_particle_rule_counts_the_second_filter_of_familiar_velocity_auto(machine_of_16_gib):
    n = 60_000_000  # 160 bytes each: 8.9 GiB for one filter, 17.9 GiB for two
    RunConfig().with_overrides({"filter.n_particles": n})
    with pytest.raises(CurbsideInputError, match=r"particle arrays \(two filters under familiar_velocity"):
        RunConfig().with_overrides({"filter.n_particles": n, "familiar_velocity.mode": "auto"})
    RunConfig.for_mode("gnss").with_overrides({"filter.n_particles": 10**9})  # gnss: no particles


def test_a_raster_beyond_the_machines_memory_is_refused_naming_the_resolution(machine_of_16_gib):
    layers = read_map(MAP)
    with pytest.raises(CurbsideInputError) as refused:
        rasterize_map(layers, 0.001)
    message = str(refused.value)
    assert message.startswith("filter.map.raster_resolution_m: 0.001 m cells over the map's 278 x 232 m")
    assert message.endswith("GiB, more than the 16 GiB of memory this machine has")
    assert rasterize_map(layers, 0.5).codes.size > 0  # the default is far inside


def test_localize_run_refuses_a_raster_resolution_that_cannot_fit(machine_of_16_gib, tmp_path, capsys):
    session = tmp_path / "walk"
    assert main(["simulate", "--route", "path3", "--map", str(MAP), "-o", str(session)]) == 0
    capsys.readouterr()
    out = tmp_path / "run"
    argv = ["run", str(session), "--map", str(MAP), "--set", "filter.map.raster_resolution_m=0.001",
            "-o", str(out)]
    err = _refused(capsys, argv)
    assert err.startswith("localize: error: filter.map.raster_resolution_m: 0.001 m cells over the map's")
    assert "more than the 16 GiB of memory this machine has" in err
    assert not out.exists()


def test_the_physical_memory_is_read_on_this_machine():
    have = configio.physical_memory_bytes()
    assert have is None or have > 2**28
    assert configio.beyond_memory(1) is None


# -- 2. simulate: options the walks would ignore ---------------------------------------------------------


@pytest.mark.parametrize(
    ("argv", "said"),
    [
        (["--benchmark", "sf6", "--seed", "4"],
         "--benchmark sf6: --seed does not apply to the benchmark (six fixed routes, session seeds 1..N from "
         "--seeds N, no map check)"),
        (["--benchmark", "sf6", "--seed", "4", "--map", "m.geojson", "--length-m", "50"],
         "--benchmark sf6: --seed, --map and --length-m do not apply to the benchmark"),
        (["--route", "path1", "--seeds", "4"],
         "--route path1: --seeds only applies to --benchmark (one walk: --seed S)"),
        (["--route", "path1", "--start", "-122.40", "37.79"],
         "--route path1: --start only shapes a custom route (--route custom)"),
        (["--route", "path1", "--start", "-122.40", "37.79", "--jaywalks", "1"],
         "--route path1: --start and --jaywalks only shape a custom route (--route custom)"),
    ],
    ids=["benchmark-seed", "benchmark-three", "route-seeds", "one-custom-option", "two-custom-options"],
)
def test_simulate_refuses_options_that_would_be_ignored(tmp_path, capsys, argv, said):
    out = tmp_path / "out"
    # a small extract: the old code, which ignored the options, stopped on it at once instead of simulating
    err = _refused(capsys, ["simulate", *argv, "--osm", str(SMALL_OSM), "-o", str(out)])
    assert err.startswith(f"localize: error: {said}"), err
    assert not out.exists()


def test_a_benchmark_route_outside_the_osm_extract_names_the_file(tmp_path, capsys):
    argv = ["simulate", "--route", "path1", "--osm", str(SMALL_OSM), "-o", str(tmp_path / "w")]
    err = _refused(capsys, argv)
    assert err.startswith(f"localize: error: {SMALL_OSM}: route path1 lies outside it: no footway of the "
                          "OSM extract within 80 m of (-122.4025, 37.793), the nearest is 0.")
    assert "the extract's footways span lon -122.40" in err and "leave --osm out" in err


# -- 3. the fixes' lag ------------------------------------------------------------------------------------


def test_a_fix_lag_beyond_the_ceiling_is_refused(tmp_path, capsys):
    out = tmp_path / "run"
    err = _refused(capsys, ["run", TRIAL, "--fix-lag", "1e6", "-o", str(out)])
    assert err == ("localize: error: config.fix_lag: lag_s must lie in [0, 10] s (a receiver's smoothing "
                   "lags a few seconds), got 1000000.0\n")
    assert not out.exists()


def test_an_empty_candidate_list_is_refused_not_reported_as_an_estimate(tmp_path, capsys):
    out = tmp_path / "run"
    argv = ["run", TRIAL, "--fix-lag", "auto", "--set", "fix_lag.candidates_s=[]", "-o", str(out)]
    err = _refused(capsys, argv)
    assert err.startswith("localize: error: config.fix_lag: candidates_s must list at least one lag")
    assert not out.exists()


def test_the_lag_bounds_keep_the_defaults_and_name_the_candidate():
    assert FixLagConfig(mode="fixed", lag_s=10.0).lag_s == 10.0
    assert max(FixLagConfig().candidates_s) <= 10.0
    with pytest.raises(ValueError, match=r"^candidates_s\[1\] must lie in \(0, 10\] s .*got 10\.5$"):
        FixLagConfig(candidates_s=(1.0, 10.5))


# -- 4. every refusal names the parameter at fault -----------------------------------------------------

#: Checks that relate two fields name both (with their values).
_PARTNERS = ({"hop_s", "block_s"}, {"min_accuracy_m", "max_accuracy_m"}, {"min_scale", "max_scale"},
             {"alpha_slow", "alpha_fast"})
#: Sections whose checks live elsewhere (steps.py, pdr.py, ronin/stream.py, filter/calibration.py).
_OTHER_SECTIONS = ("engine.steps", "engine.pdr", "engine.ronin", "filter.calibration")


def _refusals(base, set_one):
    """Each numeric key of ``base`` set to values that some checks refuse: (key, siblings, message)."""
    listed = parameters(base)
    for p in listed:
        section, _, leaf = p.key.rpartition(".")
        numeric = ("float" in p.kind or "int" in p.kind) and not p.kind.startswith(("tuple", "dict"))
        if not numeric or section.startswith(_OTHER_SECTIONS):
            continue
        siblings = {q.key.rpartition(".")[2] for q in listed if q.key.rpartition(".")[0] == section} - {leaf}
        for value in (-1, 0, 2, 10**6, *([] if p.kind == "int" else [0.5])):
            try:
                set_one(base, p.key, value)
            except CurbsideInputError as exc:
                yield p.key, leaf, siblings, str(exc)


@pytest.mark.parametrize(
    ("base", "set_one", "at_least"),
    [(RunConfig.for_mode("fused"), lambda c, k, v: c.with_overrides({k: v}), 100),
     (RunConfig.for_mode("paper"), lambda c, k, v: c.with_overrides({k: v}), 100),
     (SegmentationConfig(), lambda c, k, v: with_overrides(c, {k: v}), 20)],
    ids=["fused", "paper", "osmseg"],
)
def test_every_refused_value_is_named_alone(base, set_one, at_least):
    """No grouped message (``motion noise parameters must be non-negative``): each refusal names the
    field set, and of its section's other fields only the one a relation ties it to."""
    refusals = list(_refusals(base, set_one))
    assert len(refusals) >= at_least
    for key, leaf, siblings, message in refusals:
        named = {name for name in siblings | {leaf}
                 if re.search(rf"(?<![\w.]){re.escape(name)}(?![\w\[])", message)}
        allowed = {leaf} | set().union(*(pair for pair in _PARTNERS if leaf in pair))
        assert leaf in named and named <= allowed, (key, message)


@pytest.mark.parametrize(
    ("key", "value", "said"),
    [
        ("filter.motion.heading_noise_deg", -1,
         "config.filter.motion: heading_noise_deg must be non-negative, got -1.0"),
        ("filter.map.segment_reach_m", 0, "config.filter.map: segment_reach_m must be positive, got 0.0"),
        ("filter.recovery.trigger_ratio", 2,
         "config.filter.recovery: trigger_ratio must lie in (0, 1], got 2.0"),
        ("engine.cadence_s", 0, "config.engine: cadence_s must be positive, got 0.0"),
        ("familiar_velocity.min_samples", 0,
         "config.familiar_velocity: min_samples must be at least 1, got 0"),
    ],
)
def test_the_reviewed_refusals_read_as_one_named_value(key, value, said):
    with pytest.raises(CurbsideInputError) as refused:
        RunConfig().with_overrides({key: value})
    assert str(refused.value) == said


def test_osmseg_build_names_the_width_it_refuses(tmp_path, capsys):
    bbox = ["--bbox", "-122.4040", "37.7920", "-122.4010", "37.7945"]
    build = ["build", *bbox, "-o", str(tmp_path / "m.geojson")]
    err = _refused(capsys, [*build, "--set", "crosswalk_width_m=0"], osmseg_main)
    assert err == "osmseg: error: config: crosswalk_width_m must be positive, got 0.0\n"
    err = _refused(capsys, [*build, "--set", "default_carriageway_width_m.residential=0"], osmseg_main)
    assert err == ("osmseg: error: config: default_carriageway_width_m.residential must be a positive "
                   "number, got 0\n")


def test_require_names_only_the_values_that_break_the_rule():
    with pytest.raises(ValueError, match=r"^b and c must be positive, got 0 and -1$"):
        require("be positive", lambda v: v > 0, {"a": 1, "b": 0, "c": -1})
    require("be positive", lambda v: v > 0, {"a": 1})


# -- 5. the particle count's description ---------------------------------------------------------------


def test_the_particle_count_says_which_value_is_the_papers(capsys):
    assert main(["parameters", "--mode", "paper", "filter.n_particles"]) == 0
    said = " ".join(capsys.readouterr().out.split())
    assert said.startswith("filter.n_particles = 500 (int)")
    assert "curbside fused's default: 2000; the paper's, and its preset's (`--mode paper`): 500" in said


@pytest.mark.parametrize(("make", "message"), [
    (lambda: StepConfig(min_interval_s=2.0), "min_interval_s must be under max_interval_s, got 2.0 and 1.1"),
    (lambda: StepConfig(lowpass_taps=4), "lowpass_taps must be odd and at least 3, got 4"),
    (lambda: RoninStreamConfig(batch_size=0), "batch_size must be positive, got 0"),
    (lambda: CalibrationConfig(prior_persistence=2), r"prior_persistence must lie in \[0, 1\], got 2"),
    (lambda: CalibrationConfig(temperature=0), "temperature must be positive, got 0"),
])
def test_the_footstep_ronin_and_calibration_sections_name_the_field_too(make, message):
    with pytest.raises(ValueError, match=message):
        make()
