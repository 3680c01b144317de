"""curbside: which side of which street a pedestrian is on, from OpenStreetMap, GNSS and inertial odometry.

Stages, one sub-package each:

- :mod:`curbside.osmseg` -- OpenStreetMap to building, street, crosswalk and sidewalk polygons.
- :mod:`curbside.localize` -- sessions, RoNIN inertial odometry, the map-aware particle filter.
- :mod:`curbside.evaluate` -- ground truth, the paper's metrics, simulation, reports.

Map data © OpenStreetMap contributors (ODbL 1.0).
"""

__version__ = "0.2.0.dev0"
