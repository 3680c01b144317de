"""Fuzzing ``osmseg build`` with odd but legal OSM: a map or a one-line input error, never a crash."""

from __future__ import annotations

import os

import shapely
from hypothesis import HealthCheck, given, settings
from osm_fuzz import osm_scene

from curbside.errors import CurbsideInputError
from curbside.osmseg.build import build_map
from curbside.osmseg.mapio import CLASSES

#: Examples per run: bounded so that ``make test`` stays fast; raise it to hunt (``CURBSIDE_FUZZ_EXAMPLES``).
MAX_EXAMPLES = int(os.environ.get("CURBSIDE_FUZZ_EXAMPLES", "40"))
#: ``make test`` replays the same examples; a hunt (``CURBSIDE_FUZZ_EXAMPLES`` set) draws new ones.
HUNTING = "CURBSIDE_FUZZ_EXAMPLES" in os.environ


@settings(
    max_examples=MAX_EXAMPLES,
    deadline=None,
    derandomize=not HUNTING,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(document=osm_scene())
def test_build_gives_a_map_or_an_input_error(document: str, tmp_path) -> None:
    path = tmp_path / "scene.osm"
    path.write_text(document, encoding="utf-8")
    try:
        layers = build_map(osm_file=path)
    except CurbsideInputError as exc:
        assert "\n" not in str(exc)
        return
    gdf = layers.gdf
    assert len(gdf) > 0
    assert set(gdf["class"]) <= set(CLASSES)
    geoms = gdf.geometry.values
    assert shapely.is_valid(geoms).all()
    assert (shapely.get_type_id(geoms) == 3).all()
    buildings = geoms[gdf["class"].to_numpy() == "building"]
    # The building layer is a clean coverage: no two buildings overlap.
    assert abs(shapely.area(buildings).sum() - shapely.union_all(buildings).area) < 1e-3
