"""What the tracking service answers about a live session: its latest estimate, as ``Estimate`` fields."""

from __future__ import annotations

import math
from typing import Any

from curbside.localize.live import LiveSession
from curbside.localize.serve.models import Estimate
from curbside.localize.track_result import place_text, sidewalk_shapes
from curbside.osmseg.places import SidewalkPlace

#: Every field of an estimate; those without a value are null.
_ESTIMATE_FIELDS = tuple(Estimate.model_fields)


def _finite(value: float | None) -> float | None:
    return float(value) if value is not None and math.isfinite(value) else None


def estimate_of(
    live: LiveSession, places: dict[str, SidewalkPlace], warnings: list[str] | None = None
) -> dict[str, Any]:
    """The session's latest estimate (fields of :class:`~curbside.localize.serve.models.Estimate`).

    Parameters
    ----------
    live
        The session.
    places
        Street and compass side of each sidewalk segment of the service's map; ``place`` says the
        estimate is off the sidewalk when it lies farther than
        :data:`~curbside.localize.track_result.OFF_SIDEWALK_M` from the segment
        (:func:`~curbside.localize.track_result.place_text`).
    warnings
        This request's own warnings (fixes dropped for arriving late); what keeps the estimate from
        answering (:meth:`~curbside.localize.live.LiveSession.notices`) and why a session cannot go on
        follow them.

    Returns
    -------
    dict
        Position fields are ``None`` until the filter has made its first update.
    """
    rows = live.rows
    warnings = [*(warnings or []), *live.notices()]
    if live.failed:
        warnings.append(f"the session cannot go on: {live.failed}")
    out: dict[str, Any] = dict.fromkeys(_ESTIMATE_FIELDS)
    out.update(
        {
            "status": "failed" if live.failed else "tracking" if rows else "starting",
            "recoveries": live.recoveries,
            "unseen_velocity_from_s": None if live.engine is None else live.engine.unseen_velocity_from_s,
            "updates": len(rows),
            "data_until": _finite(live.received_until),
            "warnings": warnings,
        }
    )
    if not rows:
        return out
    row = rows[-1]
    lon, lat = live.frame.to_lonlat(row.x, row.y)
    place = places.get(row.segment_id) if row.segment_id else None
    distance_m = None
    if row.segment_id and live.map_layers is not None:
        shapes = sidewalk_shapes(live.map_layers)
        distance_m = _finite(float(shapes.distances_m([row.segment_id], [row.x], [row.y])[0]))
    out.update(
        t=row.t,
        lat=float(lat),
        lon=float(lon),
        accuracy_m=_finite(row.accuracy_m),
        segment_id=row.segment_id,
        segment_prob=_finite(row.segment_prob),
        segment_distance_m=distance_m,
        street=place.street if place else None,
        side=place.side if place else None,
        place=place_text(place.label, distance_m) if place else None,
        n_eff=_finite(row.n_eff),
        motion=row.motion or None,
        update=row.kind,
        gnss_used=bool(row.fix_used),
        lag_s=_finite(live.received_until - row.t),
    )
    return out
