"""``HEAD /tracks/{id}/{name}`` and several byte ranges in one ``GET``.

Before, a HEAD was a 405 (``Allow: GET``): a download manager or resumable fetcher could not learn the
size, ETag and ``Accept-Ranges`` before its ranged GET. Several ranges got the whole file; now they get
a ``multipart/byteranges`` 206, bounded against the abuse RFC 9110 section 17.15 warns of. A
``Range`` with a number of more than 4300 digits was a 500.

Loopback only: the FastAPI test client in process, and uvicorn on 127.0.0.1 for the framing.
"""

from __future__ import annotations

import http.client
import os

import pytest
from fastapi.testclient import TestClient
from serve_fixtures import client_for, live_service

from curbside.localize.serve import service as service_module
from curbside.localize.serve.app import create_app
from curbside.localize.serve.download import MAX_RANGES, OpenFileResponse
from curbside.localize.serve.store import TrackStore

TOKEN = "head-ranges-token-0123456789"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
#: The headers a HEAD must share with its GET (``content-type`` apart: a multipart boundary is new
#: in every reply).
SAME = ("content-length", "content-range", "accept-ranges", "etag", "last-modified")


pytestmark = pytest.mark.usefixtures("cache_in_tmp")


def _saved(tmp_path, walk_result, session_id: str = "walked"):
    info = {"map": None, "created": "2024-01-01T00:00:00+00:00", "ended": "2024-01-01T00:01:00+00:00",
            "reason": "deleted", "start": None, "failed": None}
    return TrackStore(tmp_path / "data" / "tracks").save(session_id, walk_result, info)


def _parts(reply) -> list[tuple[dict[str, str], bytes]]:
    """The parts of a ``multipart/byteranges`` reply: each one's headers and bytes."""
    kind, _, boundary = reply.headers["content-type"].partition("; boundary=")
    assert kind == "multipart/byteranges" and boundary
    chunks = (b"\r\n" + reply.content).split(f"\r\n--{boundary}".encode())
    assert chunks[0] == b"" and chunks[-1] == b"--\r\n"
    parts = []
    for chunk in chunks[1:-1]:
        head, _, data = chunk.removeprefix(b"\r\n").partition(b"\r\n\r\n")
        parts.append((dict(line.split(": ", 1) for line in head.decode().split("\r\n")), data))
    return parts


# -- HEAD -----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["track.csv", "track.geojson", "run.json"])
@pytest.mark.parametrize(
    "asked",
    ["", "bytes=0-99", "bytes=100-", "bytes=-50", "bytes=0-9,500-599", "bytes=999999-", "bytes=9-0",
     "items=0-9"],
)
def test_head_sends_the_headers_of_the_get_and_no_body(tmp_path, ronin_model, walk_result, name, asked):
    _saved(tmp_path, walk_result)
    headers = {"Range": asked} if asked else {}
    with client_for(tmp_path, ronin_model) as client:
        got = client.get(f"/tracks/walked/{name}", headers=headers)
        head = client.head(f"/tracks/walked/{name}", headers=headers)
    assert head.status_code == got.status_code, head.text
    assert head.content == b""
    assert {k: head.headers.get(k) for k in SAME} == {k: got.headers.get(k) for k in SAME}
    assert head.headers["content-type"].partition(";")[0] == got.headers["content-type"].partition(";")[0]
    assert int(got.headers["content-length"]) == len(got.content)


def test_head_of_a_whole_file_says_its_size_etag_and_ranges(tmp_path, ronin_model, walk_result):
    folder = _saved(tmp_path, walk_result)
    with client_for(tmp_path, ronin_model) as client:
        head = client.head("/tracks/walked/track.csv")
        etag = head.headers["etag"]
        again = client.head("/tracks/walked/track.csv", headers={"Range": "bytes=5-", "If-Range": etag})
        other = client.head("/tracks/walked/track.csv", headers={"Range": "bytes=5-", "If-Range": '"x"'})
    size = (folder / "track.csv").stat().st_size
    assert head.status_code == 200 and int(head.headers["content-length"]) == size
    assert head.headers["accept-ranges"] == "bytes"
    assert head.headers["content-type"] == "text/csv; charset=utf-8"
    assert again.status_code == 206 and again.headers["content-range"] == f"bytes 5-{size - 1}/{size}"
    assert other.status_code == 200 and int(other.headers["content-length"]) == size


def test_head_needs_the_token_and_is_a_404_where_get_is(tmp_path, ronin_model, walk_result):
    _saved(tmp_path, walk_result)
    with client_for(tmp_path, ronin_model, token=TOKEN) as client:
        refused = client.head("/tracks/walked/track.csv")
        assert refused.status_code == 401 and refused.headers["www-authenticate"] == "Bearer"
        assert client.head("/tracks/walked/track.csv", headers=AUTH).status_code == 200
        for path in ("/tracks/nobody/track.csv", "/tracks/walked/meta.json"):
            got, head = client.get(path, headers=AUTH), client.head(path, headers=AUTH)
            assert got.status_code == head.status_code == 404 and head.content == b""
        assert client.delete("/tracks/walked", headers=AUTH).status_code == 200
        assert client.head("/tracks/walked/track.csv", headers=AUTH).status_code == 404


def test_head_closes_the_file_it_opened(tmp_path, ronin_model, walk_result, monkeypatch):
    _saved(tmp_path, walk_result)
    opened = []
    made = OpenFileResponse.__init__

    def recording(self, file, media_type):
        opened.append(file)
        made(self, file, media_type)

    monkeypatch.setattr(OpenFileResponse, "__init__", recording)
    with client_for(tmp_path, ronin_model) as client:
        before = len(os.listdir("/proc/self/fd"))
        for asked in ("bytes=0-", "bytes=0-9", "bytes=0-9,500-599", "bytes=999999-") * 25:
            reply = client.head("/tracks/walked/run.json", headers={"Range": asked})
            assert reply.status_code in (200, 206, 416)
        after = len(os.listdir("/proc/self/fd"))
    assert len(opened) == 100 and all(file.closed for file in opened)
    assert after - before < 5  # no descriptor per request


def _deleting_as_the_reply_starts(app, service, session_id: str):
    """``app`` where ``DELETE /tracks/{session_id}`` runs after a file route has returned its response,
    before the response starts."""

    async def wrapped(scope, receive, send):
        async def send_after_deleting(message):
            if message["type"] == "http.response.start" and service.store.folder(session_id) is not None:
                await service.delete_track(session_id)
            await send(message)

        is_file = scope["type"] == "http" and scope["path"].count("/") == 3
        await app(scope, receive, send_after_deleting if is_file else send)

    return wrapped


def test_head_survives_the_track_being_deleted_under_it(tmp_path, ronin_model, walk_result):
    folder = _saved(tmp_path, walk_result)
    size = (folder / "track.csv").stat().st_size
    config = service_module.ServiceConfig(data_dir=tmp_path / "data")
    service = service_module.TrackingService(config, ronin_model)
    with TestClient(_deleting_as_the_reply_starts(create_app(config, service), service, "walked")) as client:
        head = client.head("/tracks/walked/track.csv", headers={"Range": "bytes=-50"})
        assert not folder.exists()
        assert head.status_code == 206
        assert head.headers["content-range"] == f"bytes {size - 50}-{size - 1}/{size}"
        assert client.head("/tracks/walked/track.csv").status_code == 404


# -- several ranges -------------------------------------------------------------------------------------


def test_several_ranges_are_a_multipart_reply_in_the_order_asked(tmp_path, ronin_model, walk_result):
    folder = _saved(tmp_path, walk_result)
    data = (folder / "track.csv").read_bytes()
    size = len(data)
    with client_for(tmp_path, ronin_model) as client:
        reply = client.get("/tracks/walked/track.csv", headers={"Range": f"bytes=0-9, 500-599,-20,{size}-"})
    assert reply.status_code == 206 and "content-range" not in reply.headers
    assert int(reply.headers["content-length"]) == len(reply.content)
    spans = [(0, 10), (500, 600), (size - 20, size)]  # the range past the end is left out
    assert _parts(reply) == [
        ({"Content-Type": "text/csv; charset=utf-8", "Content-Range": f"bytes {a}-{b - 1}/{size}"}, data[a:b])
        for a, b in spans
    ]


@pytest.mark.parametrize(
    ("asked", "span"),
    [("bytes=0-99,50-149", (0, 150)), ("bytes=0-99,10-19", (0, 100)), ("bytes=0-99,150-199", (0, 200)),
     ("bytes=0-9,20000000-", (0, 10))],
)
def test_ranges_that_overlap_or_nearly_touch_are_sent_as_one(tmp_path, ronin_model, walk_result, asked, span):
    folder = _saved(tmp_path, walk_result)
    data = (folder / "track.csv").read_bytes()
    with client_for(tmp_path, ronin_model) as client:
        reply = client.get("/tracks/walked/track.csv", headers={"Range": asked})
    assert reply.status_code == 206
    assert reply.headers["content-range"] == f"bytes {span[0]}-{span[1] - 1}/{len(data)}"
    assert reply.content == data[span[0]:span[1]]


def test_abusive_or_malformed_range_sets_get_the_whole_file(tmp_path, ronin_model, walk_result):
    folder = _saved(tmp_path, walk_result)
    data = (folder / "track.csv").read_bytes()
    too_many = ",".join(f"{200 * k}-{200 * k + 9}" for k in range(MAX_RANGES + 1))
    at_most = ",".join(f"{200 * k}-{200 * k + 9}" for k in range(MAX_RANGES))
    assert len(data) > 200 * MAX_RANGES
    with client_for(tmp_path, ronin_model) as client:
        for asked in (f"bytes={too_many}", "bytes=500-599,0-9", "bytes=0-9,x-5", "bytes=0-9,", "bytes=,",
                      "bytes=" + "9" * 5000 + "-", "bytes=0-" + "9" * 5000):
            reply = client.get("/tracks/walked/track.csv", headers={"Range": asked})
            assert (reply.status_code, reply.content) == (200, data), asked[:40]
        assert len(_parts(client.get("/tracks/walked/track.csv", headers={"Range": f"bytes={at_most}"}))) == \
            MAX_RANGES
        past = client.get("/tracks/walked/track.csv", headers={"Range": f"bytes={len(data)}-,-0"})
    assert past.status_code == 416 and past.headers["content-range"] == f"bytes */{len(data)}"


# -- over a real socket ---------------------------------------------------------------------------------


def test_over_uvicorn_a_head_leaves_the_connection_ready_for_the_get(tmp_path, ronin_model, walk_result):
    folder = _saved(tmp_path, walk_result)
    data = (folder / "track.geojson").read_bytes()
    with live_service(tmp_path, ronin_model) as (url, _):
        connection = http.client.HTTPConnection(url.removeprefix("http://"), timeout=10)
        answers = []
        for method, asked in (("HEAD", "bytes=0-9,100-199"), ("HEAD", ""), ("GET", "bytes=-10")):
            headers = {"Range": asked} if asked else {}
            connection.request(method, "/tracks/walked/track.geojson", headers=headers)
            reply = connection.getresponse()
            answers.append((reply.status, reply.getheader("content-length"), reply.read()))
        connection.close()
    assert answers[0][0] == 206 and answers[0][2] == b""
    assert answers[1] == (200, str(len(data)), b"")
    assert answers[2] == (206, "10", data[-10:])  # one connection: the HEADs left no body behind


# -- the API reference ----------------------------------------------------------------------------------


def test_the_schema_and_docs_page_list_head_for_the_downloads(tmp_path):
    client = TestClient(create_app(service_module.ServiceConfig(data_dir=tmp_path / "data", token=TOKEN)))
    paths = client.get("/openapi.json").json()["paths"]
    assert all("head" in item for item in paths.values() if "get" in item)  # each GET has its HEAD
    download = paths["/tracks/{session_id}/{name}"]
    assert {"200", "206", "416"} <= set(download["get"]["responses"]) & set(download["head"]["responses"])
    assert set(download["get"]["responses"]["200"]["content"]) == {"text/csv", "application/geo+json",
                                                                   "application/json"}
    page = client.get("/docs").text
    assert 'HEAD</span> /tracks/{session_id}/{name} <span class="tok"' in page
    assert "<td><code>416</code></td><td>no range asked for starts before the end" in page
    assert "<code>text/csv</code>, <code>application/geo+json</code>" in page
