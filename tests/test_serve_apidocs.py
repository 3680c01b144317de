"""``/docs`` is an API reference that needs nothing from outside the service.

Before, ``/docs`` was FastAPI's Swagger UI, whose script, style and icon the browser fetches from the
jsDelivr CDN and fastapi.tiangolo.com: offline (or behind a proxy that blocks them) a blank page with
four console errors. Swagger UI moved to ``/docs/swagger``.
"""

from __future__ import annotations

import re

import pytest
from browser import chromium, console_errors
from fastapi.testclient import TestClient

from curbside.localize.serve.apidocs import api_reference_html
from curbside.localize.serve.app import create_app
from curbside.localize.serve.service import ServiceConfig

TOKEN = "apidocs-token-0123456789"
ROWS_REF = "#/components/schemas/Rows"


@pytest.fixture
def client(tmp_path) -> TestClient:
    """The app with a token, without its lifespan (no model, no session: the pages need none)."""
    return TestClient(create_app(ServiceConfig(data_dir=tmp_path / "data", token=TOKEN)))


def test_docs_is_a_whole_reference_that_loads_nothing(client):
    answer = client.get("/docs")  # no token: the page holds no data
    assert answer.status_code == 200 and answer.headers["content-type"].startswith("text/html")
    page = answer.text
    schema = client.get("/openapi.json").json()
    for path, item in schema["paths"].items():
        for method in item:
            assert f'{method.upper()}</span> {path}' in page, (method, path)
    for name in schema["components"]["schemas"]:
        assert f'id="schema-{name}"' in page
    assert "<script" not in page and "<link" not in page and "@import" not in page
    assert not re.search(r'(src|href)="(https?:)?//', page), "an outside resource"
    assert page.count('class="tok"') >= 2  # the token's routes are marked, /health is not
    assert "GET</span> /health</h3>" in page


def test_swagger_ui_is_still_there_for_those_who_can_load_it(client):
    answer = client.get("/docs/swagger")
    assert answer.status_code == 200 and "/openapi.json" in answer.text and "swagger-ui" in answer.text
    assert "/docs" not in client.get("/openapi.json").json()["paths"]


def test_types_render_as_links_unions_and_arrays():
    schema = {
        "info": {"title": "t", "version": "1"},
        "paths": {"/x/{id}": {"post": {
            "summary": "S", "security": [{"HTTPBearer": []}],
            "parameters": [{"name": "id", "in": "path", "required": True, "schema": {"type": "string"}}],
            "requestBody": {"content": {"application/json": {"schema": {"$ref": ROWS_REF}}}},
            "responses": {"200": {"description": "ok", "content": {"application/json": {"schema": {
                "anyOf": [{"type": "array", "items": {"type": "number"}}, {"type": "null"}]}}}},
                "404": {"description": "Not Found"}, "409": {"description": "Conflict"}},
        }}},
        "components": {"schemas": {"Rows": {"properties": {
            "kind": {"enum": ["imu", "gnss"]}, "t": {"type": "number", "format": "double", "default": 0}},
            "required": ["kind"]}}},
    }  # fmt: skip
    page = api_reference_html(schema)
    assert '<a href="#schema-Rows">Rows</a>' in page and 'id="schema-Rows"' in page
    assert "array of number | null" in page
    assert 'one of <code>&quot;imu&quot;</code>, <code>&quot;gnss&quot;</code>' in page
    assert "number (double)" in page
    assert page.count("<tr>") == 2 + 2 + 4 + 3  # parameters, body, responses (an error a row), fields


def test_docs_reads_on_a_phone_without_console_errors(client, tmp_path):
    page = tmp_path / "docs.html"
    page.write_text(client.get("/docs").text, encoding="utf-8")
    with chromium(1200, 900) as driver:
        driver.execute_cdp_cmd("Emulation.setDeviceMetricsOverride", {
            "width": 390, "height": 844, "deviceScaleFactor": 2, "mobile": True})
        driver.get(page.as_uri())
        assert driver.execute_script("return document.documentElement.scrollWidth") <= 390
        assert console_errors(driver) == []
