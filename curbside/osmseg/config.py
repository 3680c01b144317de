"""Every parameter of ``osmseg build``: the widths and rules that turn OSM tags into polygons.

:class:`SegmentationConfig` is passed down the build (:func:`curbside.osmseg.build.build_map`) to each
stage and written whole into the map's metadata (``params``), so a map says which parameters made it.
``docs/osmseg.md`` gives the source of each value.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from curbside.configio import check, non_negative, positive, require

#: Street names in a language (``name:en``, ``name:zh``, ``name:zh-Hant``): the reader keeps these of
#: highway ways too, so that a map can name its streets in the walker's language.
LOCALISED_NAME = re.compile(r"name:[a-z]{2,3}(?:-[A-Za-z]{2,8})*")
#: What an unmarked crossing (``crossing=unmarked``, ``crossing:markings=no``) may become.
UNMARKED_CHOICES = ("crosswalk", "street")
#: Elements this far (m) outside the area to build are still read, so that sidewalks, crosswalks and
#: buildings at its edge come out whole before the map is clipped.
READ_MARGIN_M = 60.0


def _positive_number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and value > 0


def _is_name_key(key: object) -> bool:
    return isinstance(key, str) and (key in ("name", "ref") or LOCALISED_NAME.fullmatch(key) is not None)


def _default_carriageway_widths() -> dict[str, float]:
    return {
        "motorway": 11.0, "motorway_link": 5.0, "trunk": 11.0, "trunk_link": 5.0,
        "primary": 13.0, "primary_link": 5.0, "secondary": 12.0, "secondary_link": 5.0,
        "tertiary": 10.0, "tertiary_link": 5.0, "residential": 8.0, "unclassified": 7.0,
        "living_street": 6.0, "service": 5.0, "busway": 7.0,
    }  # fmt: skip


def _default_parking_widths() -> dict[str, float]:
    return {"parallel": 2.2, "lane": 2.2, "diagonal": 4.5, "perpendicular": 5.0}


@dataclass(frozen=True)
class SegmentationConfig:
    """The derivation rules and widths of ``osmseg build`` (metres, square metres for areas).

    Attributes
    ----------
    default_carriageway_width_m
        Carriageway width (curb to curb) per ``highway`` class when a way has neither ``width`` nor
        ``lanes``. Its keys are also the classes that make carriageway.
    lane_width_m
        Width of one traffic lane when the width comes from ``lanes`` (osm2streets uses 3.0 m too).
    parking_width_m
        Width of one side's on-street parking by ``parking:*`` orientation or ``parking:lane:*`` value
        (keys ``parallel``, ``lane``, ``diagonal``, ``perpendicular``; ``half_on_kerb`` takes half of
        ``lane``).
    assumed_parking_width_m
        Parking assumed on each side of a street with sidewalks whose width comes from ``lanes`` and
        that has no ``parking*`` tag (downtown streets mostly have curbside parking or loading lanes).
    min_carriageway_half_width_m
        Narrowest half carriageway after mapped sidewalks and building lines have capped it.
    max_tagged_carriageway_width_m
        A road's ``width`` or ``est_width`` above this is taken for a tagging error (a unit slip such as
        ``width=0.5 km``, or a right-of-way width) and ignored with a warning: the width then comes from
        ``lanes`` or the class default. Boulevards wider than this are mapped as several ways.
    cycle_lane_width_m
        Width of one painted cycle lane (``cycleway*=lane``).
    sidewalk_highways
        ``highway`` classes whose sidewalks become ``sidewalk`` segments (motorways, service roads and
        busways have none).
    sidewalk_depth_m
        Depth of a derived sidewalk, curb to building line, where no building is closer and no
        separately mapped sidewalk lies further out (the segment then reaches its far edge).
    min_sidewalk_width_m
        Least sidewalk kept between a derived curb and the building line where no sidewalk is mapped.
    street_name_keys
        The tags a sidewalk segment's ``street`` is read from, in order of preference: ``name``, ``ref``
        and ``name:<language>`` (``("name:nl", "name", "ref")`` names Brussels' streets in Dutch where
        OSM has it, by their ``name`` elsewhere). ``osmseg build --name-tag`` sets it.
    max_median_width_m
        Widest median (curb to curb) between the two one-way halves of a dual carriageway: the sides
        of a divided road that face each other across it get no sidewalk
        (:func:`curbside.osmseg.medians.median_sides`); 0 turns the rule off.
    min_refuge_width_m
        Narrowest median (curb to curb) that a dual carriageway opens by taking the parking assumed
        on a half (``assumed_parking_width_m``) off the side that faces the other half: that parking
        is taken off only along the stretches where the median it opens is at least this wide (the
        usual least depth of a pedestrian refuge island, 1.8 m / 6 ft). A value wider than any median
        (e.g. 99) keeps the parking on every side.
    mapped_sidewalk_width_m
        Width of a separately mapped sidewalk (``footway=sidewalk``) without a ``width`` tag.
    mapped_sidewalk_search_m
        How far from a road's centreline a mapped sidewalk (or a building) may lie and still set that
        side's curb, or widen that side's sidewalk segment out to it.
    crosswalk_width_m
        Width of a crosswalk without a ``width`` tag (US crosswalks: 3 m / 10 ft).
    crosswalk_overlap_m
        How far crosswalks reach past the curb so that they join the sidewalk on both ends.
    passage_width_m
        Width of a walkable passage carved through a building by a footway, corridor or platform
        without a ``width`` tag (roads use their carriageway width).
    passage_island_area_m2, passage_island_thickness_m
        Pieces of a carved building smaller than this area, or thinner than this (2 x area /
        perimeter), are open floor between passages.
    unmarked_crossing_as
        What ``crossing=unmarked`` becomes: ``"crosswalk"`` or ``"street"``.
    min_polygon_area_m2
        Polygons smaller than this are dropped as slivers.
    """

    default_carriageway_width_m: dict[str, float] = field(default_factory=_default_carriageway_widths)
    lane_width_m: float = 3.0
    parking_width_m: dict[str, float] = field(default_factory=_default_parking_widths)
    assumed_parking_width_m: float = 2.2
    min_carriageway_half_width_m: float = 1.5
    max_tagged_carriageway_width_m: float = 60.0
    cycle_lane_width_m: float = 1.5
    sidewalk_highways: tuple[str, ...] = (
        "trunk", "trunk_link", "primary", "primary_link", "secondary", "secondary_link",
        "tertiary", "tertiary_link", "residential", "unclassified", "living_street",
    )  # fmt: skip
    sidewalk_depth_m: float = 5.0
    min_sidewalk_width_m: float = 2.5
    max_median_width_m: float = 20.0
    min_refuge_width_m: float = 1.8
    street_name_keys: tuple[str, ...] = ("name", "ref")
    mapped_sidewalk_width_m: float = 2.0
    mapped_sidewalk_search_m: float = 25.0
    crosswalk_width_m: float = 3.0
    crosswalk_overlap_m: float = 0.5
    passage_width_m: float = 3.0
    passage_island_area_m2: float = 200.0
    passage_island_thickness_m: float = 5.0
    unmarked_crossing_as: str = "crosswalk"
    min_polygon_area_m2: float = 0.5

    def __post_init__(self) -> None:
        for name in ("default_carriageway_width_m", "parking_width_m"):
            widths = getattr(self, name)
            check(isinstance(widths, dict), f"{name} must map names to widths, got {widths!r}")
            named = {f"{name}.{key}": width for key, width in widths.items()}
            require("be a positive number", _positive_number, named)
        check("lane" in self.parking_width_m, "parking_width_m needs a 'lane' width")
        positive(self, "lane_width_m", "cycle_lane_width_m", "sidewalk_depth_m", "mapped_sidewalk_width_m",
                 "mapped_sidewalk_search_m", "crosswalk_width_m", "passage_width_m",
                 "min_carriageway_half_width_m", "max_tagged_carriageway_width_m")
        non_negative(self, "assumed_parking_width_m", "min_sidewalk_width_m", "max_median_width_m",
                     "min_refuge_width_m", "crosswalk_overlap_m", "passage_island_area_m2",
                     "passage_island_thickness_m", "min_polygon_area_m2")
        highways = self.sidewalk_highways
        check(
            not isinstance(highways, str) and all(isinstance(h, str) for h in highways),
            f"sidewalk_highways must be highway class names, got {highways!r}",
        )
        names = self.street_name_keys
        check(
            not isinstance(names, str) and len(names) > 0 and all(map(_is_name_key, names)),
            "street_name_keys must be OSM name tags (name, ref, name:<language> such as name:en), "
            f"got {names!r}",
        )
        check(
            self.unmarked_crossing_as in UNMARKED_CHOICES,
            f"unmarked_crossing_as must be one of {', '.join(UNMARKED_CHOICES)}, "
            f"got {self.unmarked_crossing_as!r}",
        )
