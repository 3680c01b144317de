"""Bad input that needs no reading is refused before the heavy imports: in a fraction of a second, with
one line that names the file and the problem, and exit status 2.

A missing or misnamed input, an output that cannot be written, a bad ``--bbox`` or option: each command
checks these with the light checkers (:mod:`curbside.io`, :mod:`curbside.localize.paths`,
:mod:`curbside.osmseg.inputs`) before it imports numpy, pandas, geopandas or torch (2 to 3 s). The cases
run in one fresh interpreter, which reports after each which heavy libraries it has imported: none.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from test_cli_startup import HEAVY

from curbside.errors import CurbsideInputError
from curbside.osmseg.inputs import check_map_file
from curbside.osmseg.mapio import read_map

DATA = Path(__file__).parent / "data"
GPX = str(DATA / "sessions" / "walk.gpx")
H5 = str(DATA / "sessions" / "ipin2023-cut.h5")
MAP = str(DATA / "maps" / "crossroads.geojson")
LAT_FIRST = ["--bbox", "37.79", "-122.40", "37.80", "-122.39"]

#: (id, program, argv, what the error line says after "PROG: error: ").
CASES = [
    ("run-missing-session", "localize", ["run", "absent", "-o", "out"], "absent: no such file or folder"),
    ("run-missing-map", "localize", ["run", GPX, "--map", "gone.geojson", "-o", "out"],
     "gone.geojson: no such map file"),
    ("run-map-not-json", "localize", ["run", GPX, "--map", "text.geojson", "-o", "out"],
     "text.geojson: not readable as GeoJSON (Expecting value"),
    ("run-map-folder", "localize", ["run", GPX, "--map", "folder", "-o", "out"],
     "folder: is a folder, not a map file"),
    ("run-output-under-a-file", "localize", ["run", GPX, "-o", "file.txt/out"],
     "file.txt/out: cannot write here"),
    ("run-missing-config", "localize", ["run", "--config", "absent.json", "-o", "out"],
     "absent.json: cannot read"),
    ("run-replayed-map-gone", "localize", ["run", "--config", "run.json", "-o", "out"],
     "gone.geojson: no such file or folder (the map run.json names; give where it is now: --map MAP)"),
    ("run-single-csv", "localize", ["run", "single.csv", "-o", "out"],
     "single.csv: a single CSV is not a recording"),
    ("run-missing-weights", "localize", ["run", GPX, "--ronin-weights", "gone.pt", "-o", "out"],
     "gone.pt: no such RoNIN weights file"),
    ("run-weights-without-config", "localize", ["run", GPX, "--ronin-weights", "lone.pt", "-o", "out"],
     "lone.json: no such file: the config of lone.pt must sit beside it"),
    ("run-weights-config-given", "localize", ["run", GPX, "--ronin-weights", "model.json", "-o", "out"],
     "model.json: not a curbside RoNIN weights file (a .json is the config beside one: give the .pt)"),
    ("convert-missing", "localize", ["convert", "absent.zip", "dst"], "absent.zip: no such file or folder"),
    ("convert-output-under-a-file", "localize", ["convert", GPX, "file.txt/dst"],
     "file.txt/dst: cannot write here"),
    ("convert-no-destination", "localize", ["convert", GPX], "DST: missing destination folder"),
    ("convert-all-platform", "localize", ["convert", H5, "dst", "--all", "--platform", "android"],
     "--platform: applies to Sensor Logger exports only"),
    ("convert-list-missing", "localize", ["convert", "absent.zip", "--list"],
     "absent.zip: no such file or folder"),
    ("evaluate-missing-session", "localize", ["evaluate", "absent", "--maps", MAP, "-o", "r"],
     "absent: no such session folder"),
    ("evaluate-not-sessions", "localize", ["evaluate", "folder", "--maps", MAP, "-o", "r"],
     "folder: neither a session folder nor a folder of sessions"),
    ("evaluate-missing-map", "localize", ["evaluate", "sessions", "--maps", "gone.geojson", "-o", "r"],
     "gone.geojson: no such map file"),
    ("evaluate-output-under-a-file", "localize", ["evaluate", "sessions", "--maps", MAP, "-o", "file.txt/r"],
     "file.txt/r: cannot write here"),
    ("benchmark-missing-map", "localize", ["benchmark", "--map", "gone.geojson", "-o", "b"],
     "gone.geojson: no such map file"),
    ("benchmark-map-not-json", "localize", ["benchmark", "--map", "text.geojson", "-o", "b"],
     "text.geojson: not readable as GeoJSON"),
    ("benchmark-missing-tile", "localize", ["benchmark", "--datasf-tiles", "t*.topojson", "-o", "b"],
     "t*.topojson: no such DataSF tile file (a pattern that matched no file)"),
    ("benchmark-output-a-file", "localize", ["benchmark", "-o", "file.txt"], "file.txt: "),
    ("view-missing-run", "localize", ["view", "absent", "-o", "v.html"], "absent: no such run folder"),
    ("view-not-a-run", "localize", ["view", "folder", "-o", "v.html"], "folder: not a run folder"),
    ("view-not-html", "localize", ["view", "run", "-o", "v.txt"], "v.txt: the viewer is an HTML page"),
    ("view-missing-map", "localize", ["view", "run", "--map", "gone.geojson", "-o", "v.html"],
     "gone.geojson: no such map file"),
    ("view-missing-session", "localize", ["view", "run", "--session", "absent", "-o", "v.html"],
     "absent: no such file or folder"),
    ("build-missing-osm", "osmseg", ["build", "--osm", "absent.osm", "-o", "m.geojson"],
     "absent.osm: no such OSM file"),
    ("build-empty-osm", "osmseg", ["build", "--osm", "empty.osm", "-o", "m.geojson"],
     "empty.osm: is empty (0 bytes)"),
    ("build-not-osm", "osmseg", ["build", "--osm", "file.txt", "-o", "m.geojson"],
     "file.txt: unsupported file type"),
    ("build-bbox-lat-first", "osmseg", ["build", *LAT_FIRST, "-o", "m.geojson"],
     "--bbox: outside the lon/lat range (lon -180..180, lat -90..90); it looks like latitude first"),
    ("build-output-under-a-file", "osmseg", ["build", "-o", "file.txt/m.geojson"],
     "file.txt/m.geojson: cannot write here"),
    ("build-unknown-set", "osmseg", ["build", "--set", "nosuchkey=1", "-o", "m.geojson"],
     "--set nosuchkey: no parameter 'nosuchkey'"),
    ("show-missing-map", "osmseg", ["show", "gone.geojson", "-o", "x.png"], "gone.geojson: no such map file"),
    ("show-map-not-json", "osmseg", ["show", "text.geojson", "-o", "x.png"],
     "text.geojson: not readable as GeoJSON"),
    ("show-bad-format", "osmseg", ["show", MAP, "-o", "x.pdf"], "x.pdf: unsupported output format '.pdf'"),
    ("show-bbox-lat-first", "osmseg", ["show", MAP, *LAT_FIRST, "-o", "x.png"],
     "--bbox: outside the lon/lat range"),
    ("compare-missing-map", "osmseg", ["compare", "gone.geojson", MAP], "gone.geojson: no such map file"),
    ("compare-map-not-json", "osmseg", ["compare", MAP, "text.geojson"],
     "text.geojson: not readable as GeoJSON"),
    ("edit-missing-map", "osmseg", ["edit", "gone.geojson", "-o", "e.html"],
     "gone.geojson: no such map file"),
    ("edit-map-not-json", "osmseg", ["edit", "text.geojson", "-o", "e.html"],
     "text.geojson: not readable as GeoJSON"),
    ("edit-bbox-lat-first", "osmseg", ["edit", MAP, *LAT_FIRST, "-o", "e.html"],
     "--bbox: outside the lon/lat range"),
    ("datasf-missing-streets", "osmseg",
     ["import-datasf", "t.topojson", "--streets-from", "gone.geojson", "-o", "m.geojson"],
     "gone.geojson: no such map file"),
]

# Each case through the console script's main(), in this one interpreter; prints, per case, the exit
# status, what went to stderr and the heavy libraries imported so far.
_BATCH = textwrap.dedent(
    """
    import contextlib, io, json, sys
    from curbside.cli import localize, osmseg

    heavy, cases = json.loads(sys.argv[1]), json.loads(sys.argv[2])
    results = []
    for prog, argv in cases:
        err = io.StringIO()
        with contextlib.redirect_stderr(err):
            try:
                status = {"localize": localize, "osmseg": osmseg}[prog].main(argv)
            except SystemExit as exc:
                status = exc.code
        results.append({"status": status, "stderr": err.getvalue(),
                        "heavy": sorted(name for name in heavy if name in sys.modules)})
    print(json.dumps(results))
    """
)


def _inputs(folder: Path) -> None:
    """The bad inputs the cases name, and a run folder and a run.json to hold them."""
    (folder / "file.txt").write_text("not a folder\n")
    (folder / "text.geojson").write_text("hello, not JSON\n")
    (folder / "single.csv").write_text("time,seconds_elapsed\n")
    (folder / "empty.osm").touch()
    (folder / "lone.pt").write_bytes(b"weights without their config")
    (folder / "model.json").write_text("{}")
    (folder / "folder").mkdir()
    (folder / "run").mkdir()
    (folder / "sessions" / "s1").mkdir(parents=True)
    (folder / "sessions" / "s1" / "gnss.csv").write_text("t,lat,lon,accuracy_m\n")
    (folder / "run" / "track.csv").write_text("t,lat,lon\n")
    (folder / "run.json").write_text(json.dumps({"config": {}, "session": GPX, "map": "gone.geojson"}))


@pytest.fixture(scope="module")
def refusals(tmp_path_factory) -> dict[str, dict]:
    """Each case's result, by id, from one fresh interpreter; nothing is written."""
    folder = tmp_path_factory.mktemp("bad-input")
    _inputs(folder)
    before = sorted(p.name for p in folder.rglob("*"))
    cases = [[prog, argv] for _, prog, argv, _ in CASES]
    out = subprocess.run([sys.executable, "-c", _BATCH, json.dumps(HEAVY), json.dumps(cases)], cwd=folder,
                         capture_output=True, text=True, check=True, timeout=120).stdout
    assert sorted(p.name for p in folder.rglob("*")) == before, "a refused command wrote something"
    return {case[0]: result for case, result in zip(CASES, json.loads(out), strict=True)}


@pytest.mark.parametrize(("case", "prog", "message"), [(c, p, m) for c, p, _, m in CASES],
                         ids=[c for c, *_ in CASES])
def test_bad_input_is_refused_before_the_heavy_imports(refusals, case, prog, message):
    result = refusals[case]
    err = result["stderr"]
    assert result["status"] == 2, err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith(f"{prog}: error: ") and message in err, err
    assert not result["heavy"], f"imported {result['heavy']} before refusing"


@pytest.mark.parametrize(
    "content", [b"", b"hello", b"[1, 2]", b'  \n"text"', b"\xef\xbb\xbf{}", b"\xff\xfe{", b"<osm/>"],
    ids=["empty", "text", "array", "string", "bom", "not-utf8", "xml"],
)
def test_the_early_map_check_refuses_as_read_map_does(tmp_path, content):
    """What the cheap check refuses, it refuses with :func:`read_map`'s message: one source for both."""
    path = tmp_path / "map.geojson"
    path.write_bytes(content)
    with pytest.raises(CurbsideInputError) as early:
        check_map_file(path)
    with pytest.raises(CurbsideInputError) as late:
        read_map(path)
    assert str(early.value) == str(late.value)


def test_the_early_map_check_leaves_the_features_to_read_map(tmp_path):
    """A file that starts as a JSON object passes the cheap check (its first bytes only are read)."""
    check_map_file(MAP)
    padded = tmp_path / "padded.geojson"
    padded.write_text("\n  " + Path(MAP).read_text(encoding="utf-8"), encoding="utf-8")
    check_map_file(padded)
    assert len(read_map(padded).gdf) == len(read_map(MAP).gdf)
    other = tmp_path / "other.geojson"
    other.write_text('{"type": "Feature"}')
    check_map_file(other)
    with pytest.raises(CurbsideInputError, match="not a GeoJSON FeatureCollection"):
        read_map(other)


def test_a_large_file_that_is_no_json_object_is_not_read_whole(tmp_path, monkeypatch):
    # An OSM extract given as --map (hundreds of MB) was read whole by the "cheap" check.
    big = tmp_path / "extract.osm.pbf"
    with open(big, "wb") as fh:
        fh.write(b"\x00\x00\x00\x0dOSMHeader")
        fh.truncate(9 * 2**20)

    def read_whole(*args, **kwargs):
        raise AssertionError("read whole")

    monkeypatch.setattr(Path, "read_text", read_whole)
    with pytest.raises(CurbsideInputError, match="not a GeoJSON FeatureCollection"):
        check_map_file(big)
