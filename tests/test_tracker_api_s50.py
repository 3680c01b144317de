"""The tracker as an app calls it: input checks, where step() starts, the dead-reckoning signal, the
widening after a gap, and the place words of an estimate (docs/filter.md, "From Python")."""

from __future__ import annotations

import math

import geopandas as gpd
import numpy as np
import pytest
from filter_maps import UTM10, X0, Y0, two_sidewalk_map

from curbside import settings
from curbside.errors import CurbsideInputError, CurbsideValueError
from curbside.localize.filter import FilterConfig, GnssFix, MotionConfig, Tracker
from curbside.localize.filter.predict import InertialPredictor
from curbside.localize.filter.step_input import MAX_SPEED_MPS
from curbside.localize.runconfig import RunConfig
from curbside.localize.track_result import EstimatePlaces, SidewalkShapes
from curbside.osmseg.mapio import MapLayers

NAN = math.nan


@pytest.fixture(autouse=True)
def _cache_in_tmp(tmp_path, monkeypatch):
    monkeypatch.setattr(settings, "cache_dir", tmp_path / "cache")


def started(t0: float = 0.0, layers: MapLayers | None = None, n: int = 300) -> Tracker:
    tracker = Tracker.from_config(layers, FilterConfig(n_particles=n), seed=0)
    if layers is None:
        tracker.start_at(t0, lat=37.79, lon=-122.40)
    else:
        tracker.start_at_pose(t0, X0, Y0 + 8.0)
    return tracker


# -- A: input checks ------------------------------------------------------------------------------


def test_times_in_milliseconds_are_refused_naming_t():
    tracker = Tracker.from_config(None, FilterConfig(n_particles=100), seed=0)
    with pytest.raises(CurbsideValueError, match=r"^t: .*milliseconds or nanoseconds"):
        tracker.start_at(1.7e12, lat=37.79, lon=-122.40)
    tracker = started()
    with pytest.raises(CurbsideValueError, match=r"^t: "):
        tracker.step(1.7e12, displacement_en=(0.0, 0.5))


def test_time_must_increase_from_one_update_to_the_next():
    tracker = started(10.0)
    with pytest.raises(CurbsideValueError, match=r"^t: 5\.0 is not after the previous update's 10\.0"):
        tracker.step(5.0, displacement_en=(0.0, 0.5))
    with pytest.raises(CurbsideValueError, match=r"^t: 10\.0 is not after"):
        tracker.step(10.0, displacement_en=(0.0, 0.5))
    tracker.step(10.5, displacement_en=(0.0, 0.5))
    with pytest.raises(CurbsideValueError, match=r"^t: 3\.0 is before the previous update's 10\.5"):
        tracker.start_at(3.0, lat=37.79, lon=-122.40)
    assert tracker.start_at(10.5, lat=37.79, lon=-122.40).t == 10.5  # a restart may repeat the time


def test_dt_must_be_positive_and_agree_with_the_update_times():
    tracker = started()
    with pytest.raises(CurbsideValueError, match=r"^dt: 550\.0 s disagrees .* 0\.55 s \(milliseconds\?\)"):
        tracker.step(0.55, velocity_en=(0.0, 1.3), dt=550.0)
    for bad in (-0.5, 0.0, NAN):
        with pytest.raises(CurbsideValueError, match=r"^dt: "):
            tracker.step(0.55, velocity_en=(0.0, 1.3), dt=bad)
    # Two sensor clocks a few samples apart agree: 0.55 s of updates, a dt of 0.6 s.
    assert tracker.step(0.55, velocity_en=(0.0, 1.3), dt=0.6) is not None


def test_motion_faster_than_a_walker_is_refused_naming_the_argument():
    tracker = started()
    with pytest.raises(CurbsideValueError, match=r"^velocity_en: moves the walker 5e\+05 m in 0\.5 s"):
        tracker.step(0.5, velocity_en=(1e6, 0.0), dt=0.5)
    with pytest.raises(CurbsideValueError, match=r"^displacement_en: .*faster than 10 m/s"):
        tracker.step(0.5, displacement_en=(0.0, 0.5 * MAX_SPEED_MPS + 3.0))
    # One footstep reported 3 ms after the previous update (the engine's closest pair) is no sprint.
    assert tracker.step(0.003, displacement_en=(1.6, 0.0)) is not None


BAD_INPUT = {
    "fix lat nan": (lambda tr: tr.fix(lat=NAN, lon=-122.40, accuracy_m=5.0), "position"),
    "fix lat text": (lambda tr: tr.fix(lat="37.79", lon=-122.40, accuracy_m=5.0), "lat"),
    "fix accuracy text": (lambda tr: tr.fix(lat=37.79, lon=-122.40, accuracy_m="5"), "accuracy_m"),
    "velocity nan": (lambda tr: tr.step(1.0, velocity_en=(NAN, 1.0), dt=1.0), r"velocity_en\[0\]"),
    "velocity scalar": (lambda tr: tr.step(1.0, velocity_en=1.3, dt=1.0), "velocity_en"),
    "displacement text": (lambda tr: tr.step(1.0, displacement_en=("1", 0.0)), r"displacement_en\[0\]"),
    "t nan": (lambda tr: tr.step(NAN, displacement_en=(0.0, 1.0)), "t"),
    "t text": (lambda tr: tr.step("1.0", displacement_en=(0.0, 1.0)), "t"),
    "no motion": (lambda tr: tr.step(1.0, velocity_en=(0.0, 1.0)), r"step\(\)"),
    "fix a plain tuple": (
        lambda tr: tr.step(1.0, displacement_en=(0, 1), gnss_fix=(0.0, 0.0, 5.0)), "gnss_fix"
    ),
    "fix accuracy None": (
        lambda tr: tr.step(1.0, displacement_en=(0, 1), gnss_fix=GnssFix(0.0, 0.0, None)),
        r"gnss_fix\.accuracy_m",
    ),
    "start at invalid fix": (lambda tr: tr.start_at_fix(2.0, GnssFix(0.0, 0.0, 0.0)), "fix"),
    "start heading nan": (
        lambda tr: tr.start_at(2.0, lat=37.79, lon=-122.40, heading_offset_rad=NAN),
        "heading_offset_rad",
    ),
}


@pytest.mark.parametrize("case", list(BAD_INPUT))
def test_bad_input_raises_one_error_type_naming_the_argument(case):
    call, argument = BAD_INPUT[case]
    with pytest.raises(CurbsideValueError, match=rf"^{argument}: ") as caught:
        call(started())
    # Both an input error (one line, exit 2 in the tools) and the ValueError the tracker raised before.
    assert isinstance(caught.value, CurbsideInputError) and isinstance(caught.value, ValueError)
    assert "\n" not in str(caught.value)


def test_a_fix_without_accuracy_is_an_invalid_fix():
    tracker = Tracker.from_config(None, FilterConfig(n_particles=100), seed=0)
    fix = tracker.fix(lat=37.79, lon=-122.40, accuracy_m=None)
    assert math.isnan(fix.accuracy_m) and not tracker.usable(fix)
    assert tracker.step(0.0, displacement_en=(0.0, 0.0), gnss_fix=fix) is None
    with pytest.raises(CurbsideValueError, match="^fix: cannot start from an invalid fix"):
        tracker.start_at_fix(0.0, fix)


# -- B: where step() starts -----------------------------------------------------------------------


def test_step_starts_only_at_a_fix_the_gnss_part_would_use():
    tracker = Tracker.from_config(None, FilterConfig(n_particles=100), seed=0)
    for accuracy_m in (60.0, 1e6):  # max_accuracy_m is 50
        poor = tracker.fix(lat=37.79, lon=-122.40, accuracy_m=accuracy_m)
        assert tracker.step(0.0, displacement_en=(0, 0), gnss_fix=poor) is None
    assert not tracker.started
    good = tracker.fix(lat=37.79, lon=-122.40, accuracy_m=5.0)
    estimate = tracker.step(1.0, displacement_en=(0, 0), gnss_fix=good)
    assert tracker.started and estimate.accuracy_m < 10.0


def test_step_skips_a_first_fix_outside_the_map(caplog):
    tracker = Tracker.from_config(two_sidewalk_map(), FilterConfig(n_particles=100), seed=0)
    far = GnssFix(X0 + 5000.0, Y0, 5.0)  # a stale last-known place, 5 km away
    with caplog.at_level("WARNING"):
        assert tracker.step(0.0, displacement_en=(0, 0), gnss_fix=far) is None
        assert tracker.step(1.0, displacement_en=(0, 0), gnss_fix=far) is None
    assert sum("outside the map's extent" in r.message for r in caplog.records) == 1  # said once
    with pytest.raises(CurbsideInputError, match="outside the map's extent"):
        tracker.start_at_pose(1.5, far.x, far.y)  # the same rule as a start pose
    estimate = tracker.step(2.0, displacement_en=(0, 0), gnss_fix=GnssFix(X0, Y0 + 8.0, 5.0))
    assert estimate is not None and math.hypot(estimate.x - X0, estimate.y - Y0 - 8.0) < 10.0


# -- C: the dead-reckoning signal and the gap -------------------------------------------------------


def test_seconds_since_fix_grows_without_fixes_and_with_fixes_that_disagree():
    tracker = Tracker.from_config(None, FilterConfig(n_particles=300), seed=0)
    assert tracker.seconds_since_fix() == math.inf
    tracker.step(0.0, displacement_en=(0, 0), gnss_fix=tracker.fix(lat=37.79, lon=-122.40, accuracy_m=5.0))
    good = tracker.fix(lat=37.79, lon=-122.40, accuracy_m=5.0)
    for k in range(1, 6):
        tracker.step(float(k), displacement_en=(0, 0), gnss_fix=good)
    assert tracker.last_fix_t == 5.0 and tracker.seconds_since_fix() == 0.0
    for k in range(6, 21):  # a GNSS outage
        tracker.step(float(k), displacement_en=(0, 0))
    assert tracker.seconds_since_fix() == 15.0 and tracker.seconds_since_fix(30.0) == 25.0
    far = tracker.fix(lat=37.80, lon=-122.40, accuracy_m=5.0)  # 1.1 km north: usable, but no agreement
    for k in range(21, 31):
        tracker.step(float(k), displacement_en=(0, 0), gnss_fix=far)
    assert tracker.usable(far) and tracker.last_fix_t == 5.0 and tracker.seconds_since_fix() == 25.0
    tracker.start_at_fix(31.0, far)  # the app's rule: start again at the next good fix
    assert tracker.seconds_since_fix() == 0.0


def test_a_long_gap_between_updates_widens_the_cloud():
    tracker = started(n=2000)
    tracker.step(1.0, displacement_en=(0, 0))
    assert tracker.last_estimate.accuracy_m < 5.0
    estimate = tracker.step(301.0, displacement_en=(0, 0))  # the app slept 5 minutes
    spread = np.hypot(tracker.particles.x.std(), tracker.particles.y.std())
    assert spread > 250.0 and estimate.accuracy_m > 200.0  # 0.7 m/s x 300 s per axis


def test_the_gap_widening_is_the_predictor_s_and_never_reached_by_the_engine():
    motion = MotionConfig()
    predictor = InertialPredictor(motion, 10, np.random.default_rng(0))
    assert predictor.gap_sigma(motion.gap_s) == 0.0
    assert predictor.gap_sigma(100.0) == pytest.approx(100.0 * motion.gap_spread_mps)
    assert RunConfig().engine.max_update_interval_s < motion.gap_s
    with pytest.raises(ValueError, match="gap_s"):
        MotionConfig(gap_s=0.0)


# -- D: place words -------------------------------------------------------------------------------


def named_map() -> MapLayers:
    """:func:`two_sidewalk_map` with a street name and sides (the service's words)."""
    gdf = two_sidewalk_map().gdf.copy()
    gdf["street"] = [None, "Main Street", "Main Street", None]
    gdf["facing_deg"] = [NAN, 0.0, 180.0, NAN]
    return MapLayers(gpd.GeoDataFrame(gdf, geometry="geometry", crs=UTM10))


def test_estimate_places_give_the_distance_and_words_of_the_service():
    layers = named_map()
    tracker = Tracker.from_config(layers, FilterConfig(n_particles=300), seed=0)
    places = EstimatePlaces(layers)
    on = places.describe(tracker.start_at_pose(0.0, X0, Y0 + 8.0))
    assert on.segment_id == "N" and on.distance_m == 0.0 and on.text == "Main Street, north side"
    estimate = tracker.start_at_pose(1.0, X0, Y0 + 26.0)  # in the open, 16 m north of the sidewalk
    place = places.describe(estimate)
    shapes = SidewalkShapes(layers)
    expected = shapes.distances_m([estimate.segment_id], [estimate.x], [estimate.y])[0]
    assert place.segment_id == "N" and place.distance_m == pytest.approx(expected)
    assert place.text == f"off the sidewalk, {math.floor(expected + 0.5)} m from Main Street, north side"
    assert places.describe(estimate._replace(segment_id=None)) == (None,) * 6


def test_estimate_places_refuse_an_estimate_in_another_frame():
    layers = named_map()
    other = Tracker.from_config(None, FilterConfig(n_particles=50), seed=0)
    estimate = other.start_at(0.0, lat=49.45, lon=11.08)._replace(segment_id="N")  # UTM 32, not 10
    with pytest.raises(CurbsideValueError, match="^estimate: its frame is not the map's CRS"):
        EstimatePlaces(layers).describe(estimate)


def test_a_clock_in_milliseconds_since_the_app_started_is_warned_about_once(caplog):
    # 20 "s" apart at every step: a 50 Hz app handing milliseconds since it started (stop 51).
    tracker = started()
    with caplog.at_level("WARNING", logger="curbside.localize.filter.tracker"):
        for k in range(1, 8):
            tracker.step(20.0 * k, displacement_en=(0.0, 0.03))
    warned = [r.getMessage() for r in caplog.records if "milliseconds" in r.getMessage()]
    assert len(warned) == 1
    assert "is t in milliseconds" in warned[0] and "20 s" in warned[0]


def test_one_gap_after_the_app_slept_is_not_warned_about(caplog):
    tracker = started()
    with caplog.at_level("WARNING", logger="curbside.localize.filter.tracker"):
        for t in (1.0, 2.0, 300.0, 301.0, 302.0, 330.0, 331.0):
            tracker.step(t, displacement_en=(0.0, 0.5))
    assert not [r for r in caplog.records if "milliseconds" in r.getMessage()]
