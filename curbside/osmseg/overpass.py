"""Stage 1 (network source): OSM elements of a bbox from Overpass, and a place name's bbox from Nominatim.

curbside sends the Overpass query itself, writes the answer's nodes, ways and relations to a temporary
OSM file with pyosmium (:func:`write_osm_file`) and reads that with
:func:`~curbside.osmseg.reader.read_osm_file`, the reader of ``--osm`` files: both sources go through
one code path, and only public APIs (no osmnx internals). Sending it itself is what makes every
failure one line: osmnx retried a busy server (HTTP 429/504) every 55 s without end, built a map
from the part of an answer that Overpass had cut short with a "runtime error" remark, called an
empty or truncated answer "no data", and could cache an answer without elements for good.

Answers are cached under ``settings.cache_dir`` (``overpass/``, ``nominatim/``; :mod:`curbside.cache`):
an entry is written only from a whole, valid answer and atomically, so a failed or interrupted
download leaves none; an entry that cannot be read is downloaded again.
"""

from __future__ import annotations

import json
import logging
import math
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import osmium
import osmnx as ox
import requests

import curbside
from curbside import cache, settings
from curbside.errors import CurbsideInputError
from curbside.io import atomic_path
from curbside.osmseg.reader import OsmData, read_osm_file

log = logging.getLogger(__name__)

BBox = tuple[float, float, float, float]

#: The Overpass tag query: every building and every highway element.
OVERPASS_TAGS: dict[str, bool] = {"building": True, "highway": True}

#: HTTP statuses with which a busy Overpass server asks to be asked again later.
BUSY_STATUSES = frozenset({429, 503, 504})

#: What requests raises when an answer stops in the middle.
BROKEN_OFF = (requests.exceptions.ChunkedEncodingError, requests.exceptions.ContentDecodingError)

#: What a build without the network can do instead.
OFFLINE_ADVICE = "build offline with --osm FILE"

#: Seconds past ``settings.overpass_timeout_s`` to wait for Overpass to answer (it stops the query then).
READ_GRACE_S = 15.0

#: Seconds Nominatim may take to answer a search once connected.
NOMINATIM_READ_TIMEOUT_S = 30.0

#: Half the side (m) of the bbox suggested around a place name that is a point.
POINT_HALF_SIDE_M = 250.0

#: The element types of OSM data, and their one-letter names in osmium; other Overpass elements are skipped.
OSM_TYPES: dict[str, str] = {"node": "n", "way": "w", "relation": "r"}

#: The longest text (UTF-8 bytes) libosmium stores in a tag key or value or a member role (OSM allows 255
#: characters).
MAX_TEXT_BYTES = 1024


class OverpassUnreachableError(CurbsideInputError):
    """The Overpass server does not answer (no network?) and no cached answer stands in."""


def write_osm_file(elements: list[dict[str, Any]], path: str | Path) -> None:
    """Write the nodes, ways and relations of an Overpass JSON answer to an OSM file with pyosmium.

    Nodes are written first, then ways, then relations (readers that look up node locations need that
    order); elements of other types are skipped.

    Parameters
    ----------
    elements
        An answer's ``elements``, each checked by :func:`element_problem`.
    path
        A new file; its name sets the format (``.osm.pbf``, ``.osm``...).
    """
    by_type: dict[str, list[dict[str, Any]]] = {kind: [] for kind in OSM_TYPES}
    for element in elements:
        if element.get("type") in by_type:
            by_type[element["type"]].append(element)
    mutable = osmium.osm.mutable
    with osmium.SimpleWriter(str(path)) as writer:
        for e in by_type["node"]:
            writer.add_node(mutable.Node(id=e["id"], location=(e["lon"], e["lat"]), tags=e.get("tags", {})))
        for e in by_type["way"]:
            writer.add_way(mutable.Way(id=e["id"], nodes=e["nodes"], tags=e.get("tags", {})))
        for e in by_type["relation"]:
            members = [(OSM_TYPES[m["type"]], m["ref"], m["role"]) for m in e["members"]]
            writer.add_relation(mutable.Relation(id=e["id"], members=members, tags=e.get("tags", {})))


def element_problem(element: Any) -> str | None:
    """What keeps :func:`write_osm_file` from writing an Overpass element, ``None`` when nothing does.

    Elements of types other than node, way and relation are not checked (they are skipped).
    """
    if not isinstance(element, dict):
        return "an element that is not a JSON object"
    kind = element.get("type")
    if kind not in OSM_TYPES:
        return None
    what = f"{kind} {element.get('id')!r}"
    if not _is_id(element.get("id")):
        return f"a {kind} without a whole-number id"
    tags = element.get("tags", {})
    if not isinstance(tags, dict):
        return f"{what} with tags that are not a JSON object"
    texts = [*tags, *tags.values()]
    if kind == "node":
        fields_ok = all(_is_number(element.get(axis), limit) for axis, limit in (("lat", 90), ("lon", 180)))
    elif kind == "way":
        refs = element.get("nodes")
        fields_ok = isinstance(refs, list) and all(_is_id(ref) for ref in refs)
    else:
        members = element.get("members")
        fields_ok = isinstance(members, list) and all(
            isinstance(m, dict) and m.get("type") in OSM_TYPES and _is_id(m.get("ref")) for m in members
        )
        texts += [m.get("role") for m in members] if fields_ok else []
    if not fields_ok:
        return f"{what} without its {_FIELDS[kind]}"
    # libosmium's PBF writer crashes the process on a NUL character, so it is refused here.
    if not all(isinstance(t, str) and "\x00" not in t and len(t.encode()) <= MAX_TEXT_BYTES for t in texts):
        return f"{what} with a tag or role that is not text of at most {MAX_TEXT_BYTES} bytes without NUL"
    return None


#: What :func:`element_problem` says an element lacks, by type.
_FIELDS = {"node": "coordinates (lat, lon)", "way": "list of node ids", "relation": "list of members"}


def _is_id(value: Any) -> bool:
    """Whether ``value`` is an OSM id: a whole number that fits 64 bits (``bool`` is not one)."""
    return type(value) is int and -(2**63) <= value < 2**63


def _is_number(value: Any, limit: float) -> bool:
    """Whether ``value`` is a JSON number within ``[-limit, limit]``."""
    return type(value) in (int, float) and -limit <= value <= limit


def overpass_reachable(url: str, timeout_s: float) -> bool:
    """Whether the Overpass server at ``url`` answers its status query within ``timeout_s``.

    Any HTTP answer counts (a server that lacks the status endpoint is still there).
    """
    try:
        requests.get(f"{url.rstrip('/')}/status", headers=_headers(), timeout=timeout_s)
    except requests.RequestException as exc:
        log.info("Overpass at %s is unreachable (%s)", url, type(exc).__name__)
        return False
    return True


def overpass_query(bbox: BBox, timeout_s: float) -> str:
    """The Overpass QL query for every building and highway element of a bbox, with their nodes.

    Parameters
    ----------
    bbox
        (west, south, east, north) WGS84 degrees.
    timeout_s
        The server-side timeout written into the query.
    """
    west, south, east, north = bbox
    box = f"({south:.7f},{west:.7f},{north:.7f},{east:.7f})"
    wanted = "".join(f'nwr["{key}"]{box};' for key in OVERPASS_TAGS)
    return f"[out:json][timeout:{int(timeout_s)}];({wanted});(._;>;);out;"


def fetch_overpass(bbox: BBox, *, margin_m: float = 60.0) -> OsmData:
    """Download buildings and highways of a bbox from Overpass (cached on disk).

    A cached answer is used without asking the network. Otherwise the server is asked for its status
    first, with ``settings.overpass_connect_timeout_s``: when it does not answer (no network), the
    build fails in seconds. A busy server (HTTP 429, 503, 504) is asked again after each wait of
    ``settings.overpass_busy_waits_s``, then given up on. The answer is written to a temporary OSM
    file (:func:`write_osm_file`) and read like an ``--osm`` file by
    :func:`~curbside.osmseg.reader.read_osm_file`, keeping the elements within ``margin_m`` of ``bbox``.

    Parameters
    ----------
    bbox
        (west, south, east, north) WGS84 degrees, already validated.
    margin_m
        The query covers this much more on every side, so that sidewalks at the edge are complete.

    Returns
    -------
    OsmData
        ``source`` is ``"overpass"``, ``bounds`` is ``bbox``.

    Raises
    ------
    OverpassUnreachableError
        The server does not answer its status query (no network?) and no answer is cached.
    CurbsideInputError
        No OSM data in the area; Overpass busy, failing, or sending an answer that is
        empty, cut short, not JSON, with an element that is not OSM data, or stopped by a runtime error
        (an incomplete map is never built).
    """
    west, south, east, north = bbox
    pad_lat = margin_m / 111_320.0
    pad_lon = pad_lat / max(math.cos(math.radians((south + north) / 2)), 1e-6)
    query_bbox = (west - pad_lon, south - pad_lat, east + pad_lon, north + pad_lat)
    url = ox.settings.overpass_url.rstrip("/")
    log.info("querying Overpass at %s for %s", url, query_bbox)
    answer = _overpass_answer(url, overpass_query(query_bbox, settings.overpass_timeout_s))
    unwritable = "cannot write Overpass's answer there ({}); set TMPDIR to a writable folder"
    try:
        folder = tempfile.TemporaryDirectory(prefix="curbside-overpass-")
    except OSError as exc:
        raise CurbsideInputError(tempfile.gettempdir(), unwritable.format(exc.strerror or exc)) from None
    with folder:
        osm_file = Path(folder.name) / "overpass-answer.osm.pbf"
        try:
            write_osm_file(answer["elements"], osm_file)
        except (OSError, RuntimeError) as exc:  # libosmium's writer raises RuntimeError on a full disk
            raise CurbsideInputError(tempfile.gettempdir(), unwritable.format(exc)) from None
        try:
            data = read_osm_file(osm_file, bbox, margin_m=margin_m)
        except CurbsideInputError:  # the reader found nothing it uses in the answer
            problem = f"no OSM buildings or highways in bbox {list(bbox)}"
            raise CurbsideInputError("overpass", problem) from None
    data.source = "overpass"
    data.bounds = bbox
    return data


def _headers() -> dict[str, str]:
    """HTTP headers: the OSM servers' usage policies ask every client to name itself."""
    return {"User-Agent": f"curbside/{curbside.__version__} ({ox.settings.http_user_agent})"}


def _overpass_answer(url: str, query: str) -> dict[str, Any]:
    """Overpass's answer to ``query``: the cached one, else downloaded and cached."""
    entry = cache.entry_path("overpass", cache.content_key("overpass-answer-v1", url, query), ".json")
    answer = _cached(entry, _overpass_json)
    if answer is not None:
        return answer
    if not overpass_reachable(url, settings.overpass_connect_timeout_s):
        problem = f"cannot reach the Overpass server (no network?); {OFFLINE_ADVICE}"
        raise OverpassUnreachableError(url, problem)
    body = _post(url, query)
    answer = _overpass_json(url, body)
    if "remark" not in answer:
        _store(entry, body)
    return answer


def _post(url: str, query: str) -> bytes:
    """The body of Overpass's answer to ``query``, asking again while the server says it is busy."""
    waits_s = list(settings.overpass_busy_waits_s)
    # The server stops at settings.overpass_timeout_s (written into the query) and says so: wait for that.
    read_timeout_s = settings.overpass_timeout_s + READ_GRACE_S
    for attempt in range(1, len(waits_s) + 2):
        try:
            response = requests.post(
                f"{url}/interpreter", data={"data": query}, headers=_headers(),
                timeout=(settings.overpass_connect_timeout_s, read_timeout_s),
            )  # fmt: skip
        except requests.ReadTimeout:
            raise CurbsideInputError(
                url, f"Overpass did not answer in {read_timeout_s:g} s; try a smaller --bbox, or again later",
            ) from None  # fmt: skip
        except requests.RequestException as exc:
            what = "the download broke off " if isinstance(exc, BROKEN_OFF) else ""
            problem = f"Overpass request failed: {what}({type(exc).__name__}); try again"
            raise CurbsideInputError(url, problem) from None
        status = f"HTTP {response.status_code} {response.reason}"
        if response.status_code not in BUSY_STATUSES:
            break
        if attempt > len(waits_s):
            raise CurbsideInputError(
                url, f"Overpass request failed: the server is busy ({status}, {attempt} tries); try again "
                f"in a few minutes, or {OFFLINE_ADVICE}",
            )  # fmt: skip
        log.warning("Overpass at %s is busy (%s); asking again in %g s", url, status, waits_s[attempt - 1])
        time.sleep(waits_s[attempt - 1])
    if not response.ok:
        raise CurbsideInputError(url, f"Overpass request failed ({status})")
    return response.content


def _json(source: str | Path, body: bytes, server: str) -> Any:
    """``body`` parsed as JSON; :class:`CurbsideInputError` when it is empty or not whole JSON."""
    text = body.strip()
    if not text:
        raise CurbsideInputError(source, f"{server} sent an empty answer; try again")
    try:
        return json.loads(text)
    except ValueError as exc:
        what = "XML or HTML (an error page?)" if text[:1] == b"<" else f"JSON cut short or malformed ({exc})"
        problem = f"{server} sent {what}, not a whole JSON answer; try again"
        raise CurbsideInputError(source, problem) from None


def _overpass_json(source: str | Path, body: bytes) -> dict[str, Any]:
    """A whole Overpass answer; a runtime error (Overpass's ``remark``) means it is incomplete."""
    answer = _json(source, body, "Overpass")
    if not isinstance(answer, dict) or not isinstance(answer.get("elements"), list):
        raise CurbsideInputError(source, "Overpass sent JSON without a list of elements; try again")
    problem = next(filter(None, map(element_problem, answer["elements"])), None)
    if problem is not None:
        raise CurbsideInputError(source, f"Overpass sent {problem}; try again")
    remark = str(answer.get("remark") or "").strip()
    if "error" in remark.lower():
        raise CurbsideInputError(
            source, f"Overpass stopped the query ({remark.splitlines()[0]}), so its answer is incomplete; "
            "try a smaller --bbox, or again later",
        )  # fmt: skip
    if remark:
        log.warning("Overpass remarked: %s", remark)
    return answer


def _cached(entry: Path, parse: Callable[[Path, bytes], Any]) -> Any | None:
    """A cache entry parsed, or ``None`` when it is absent or unreadable (then with a warning)."""
    if not entry.is_file():
        return None
    try:
        return parse(entry, entry.read_bytes())
    except (OSError, CurbsideInputError) as exc:
        log.warning("downloading again: unreadable cache entry %s (%s)", entry, getattr(exc, "problem", exc))
        return None


def _store(entry: Path, body: bytes) -> None:
    """Write a cache entry atomically; one that cannot be written costs only the download next time."""
    try:
        entry.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(entry) as tmp:
            tmp.write_bytes(body)
    except (OSError, CurbsideInputError) as exc:
        log.warning("could not write cache entry %s (%s)", entry, exc)


def geocode_bbox(place: str) -> tuple[BBox, str]:
    """The bounding box of the area a place name stands for, from Nominatim (cached on disk).

    Parameters
    ----------
    place
        A name as typed into openstreetmap.org's search box, e.g. ``"Union Square, San Francisco"``.

    Returns
    -------
    bbox, name
        (west, south, east, north) degrees of Nominatim's best match, and its full name.

    Raises
    ------
    CurbsideInputError
        Nominatim unreachable or failing, no match, or a match that is a point (a shop, an address)
        rather than an area.
    """
    source = f"--place {place!r}"
    url = ox.settings.nominatim_url.rstrip("/")
    entry = cache.entry_path("nominatim", cache.content_key("nominatim-search-v1", url, place), ".json")
    found = _cached(entry, _places)
    if found is None:
        found = _places(source, _search(url, place, source))
        if found:
            _store(entry, json.dumps(found).encode())
    if not found:
        raise CurbsideInputError(
            source, "Nominatim knows no place of that name; check the spelling, add the city or country "
            "(e.g. 'Union Square, San Francisco'), or give the area as --bbox W S E N",
        )  # fmt: skip
    return _place_bbox(source, found[0])


def _search(url: str, place: str, source: str) -> bytes:
    """The body of Nominatim's answer to a search for ``place``."""
    params = {"q": place, "format": "jsonv2", "limit": "1"}
    timeout = (settings.overpass_connect_timeout_s, NOMINATIM_READ_TIMEOUT_S)
    try:
        response = requests.get(f"{url}/search", params=params, headers=_headers(), timeout=timeout)
    except (requests.ConnectionError, requests.Timeout):
        raise CurbsideInputError(
            source, f"cannot reach the geocoder Nominatim at {url} (no network?); give the area as --bbox "
            f"W S E N, or {OFFLINE_ADVICE}",
        ) from None  # fmt: skip
    except requests.RequestException as exc:
        problem = f"Nominatim request failed ({type(exc).__name__}); try again"
        raise CurbsideInputError(source, problem) from None
    if not response.ok:
        raise CurbsideInputError(
            source, f"Nominatim request failed (HTTP {response.status_code} {response.reason}); try again "
            "later, or give the area as --bbox W S E N",
        )  # fmt: skip
    return response.content


def _places(source: str | Path, body: bytes) -> list[dict[str, Any]]:
    """Nominatim's list of matches."""
    found = _json(source, body, "Nominatim")
    if not isinstance(found, list) or not all(isinstance(match, dict) for match in found):
        raise CurbsideInputError(source, "Nominatim sent JSON that is not a list of places; try again")
    return found


def _place_bbox(source: str, match: dict[str, Any]) -> tuple[BBox, str]:
    """(west, south, east, north) and name of a Nominatim match; a point is refused."""
    name = str(match.get("display_name") or "?")
    try:
        south, north, west, east = (float(v) for v in match["boundingbox"])
        lon, lat = float(match["lon"]), float(match["lat"])
    except (KeyError, TypeError, ValueError):
        raise CurbsideInputError(source, "Nominatim sent a place without a bounding box; try again") from None
    if match.get("osm_type") == "node" or not (west < east and south < north):
        half_lat = POINT_HALF_SIDE_M / 111_320.0
        half_lon = half_lat / max(math.cos(math.radians(lat)), 1e-6)
        around = f"{lon - half_lon:.5f} {lat - half_lat:.5f} {lon + half_lon:.5f} {lat + half_lat:.5f}"
        raise CurbsideInputError(
            source, f"is a point, not an area ({name}, at {lon:.5f} {lat:.5f}); give the area around it, "
            f"e.g. --bbox {around} ({2 * POINT_HALF_SIDE_M:.0f} m across)",
        )  # fmt: skip
    return (west, south, east, north), name
