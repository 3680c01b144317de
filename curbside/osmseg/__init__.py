"""osmseg: OpenStreetMap to building, street-surface, crosswalk and sidewalk-segment polygons.

Modules, one per stage (osmnx style): :mod:`~curbside.osmseg.mapio` (the GeoJSON schema),
and the derivation, plotting and comparison stages beside it.
"""
