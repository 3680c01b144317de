"""A stranger's review of the reports: titles cut off at the figure's sides, a session given twice
counted twice, a map given twice blamed on --map-names, plurals and notes that miscount, GNSS-gap
warnings about the benchmark's own walks, and ``osmseg show``'s silence and oversized scale-bar box."""

from __future__ import annotations

import logging
import shutil
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Patch
from matplotlib.text import Text

from curbside.cli.localize import main as localize_main
from curbside.cli.osmseg import main as osmseg_main
from curbside.evaluate import figures, suite_report
from curbside.evaluate.suite import SuiteConfig
from curbside.localize.input_warnings import report_gnss_holds
from curbside.localize.runconfig import RunConfig
from curbside.localize.session import Session
from curbside.osmseg.mapio import read_map
from curbside.osmseg.plot import plot_map

MAP = Path(__file__).parent / "data" / "evaluate" / "sf-path3.geojson"
LONG_MAP = "downtown_san_francisco_hand_corrected_2024"


def _base(map_name: str) -> dict:
    return {"map": map_name, "jaywalk_weight": 0.4, "particles": 500, "gnss_sigma_factor": None}


def _runs(map_name: str, methods: tuple[str, ...]) -> list[dict]:
    """One walk per method at the base configuration, with errors and (filters) one particle cloud."""
    rng = np.random.default_rng(0)
    t = np.linspace(0, 100, 20)
    track = pd.DataFrame({"t": t, "gt_x_m": t, "gt_y_m": 0.5 * t, "x_m": t, "y_m": 0.5 * t})
    spec = {"map_name": map_name, "jaywalk_weight": 0.4, "particles": 500, "gnss_sigma_factor": None}
    return [
        {"path": "path1", "session": "path1-recorded-2024-05-01-morning", "track": track,
         "spec": {**spec, "method": m},
         "errors": pd.DataFrame({"euclid_m": rng.gamma(2, 5, 100), "missing": False}),
         "snapshots": [] if m == "gnss" else [
             {"t": 10.0, "x": rng.normal(10, 3, 100), "y": rng.normal(5, 3, 100), "fix": (12.0, 4.0, 6.0)}]}
        for m in methods
    ]


def _reliability_rows() -> list[dict]:
    curve = [{"claimed": c, "held": h} for c, h in ((0.5, 0.6), (0.68, 0.8), (0.95, 1.0))]
    return [{"subset": None, "method": m, "footsteps": 100, "calibration_error": 0.1,
             "bins": [{"mean_prob": 0.5, "share_right": 0.4, "footsteps": 10},
                      {"mean_prob": 1.0, "share_right": 1.0, "footsteps": 90}],
             "accuracy_curve": curve, "accuracy_coverage": 0.8, "accuracy_median_m": 4.0}
            for m in ("inertial", "paper", "fused")]


def _figure(kind: str, map_name: str) -> Figure:
    """Each report figure in its narrowest form: one group, one walk, one route, one method."""
    base = _base(map_name)
    if kind == "reliability":  # one group: the figure is 6 in wide
        return figures.fig_reliability(_reliability_rows(), base)
    if kind == "tracks":
        return figures.fig_tracks(_runs(map_name, ("gnss", "fused")), None, base)
    if kind == "particles":  # one filter: one panel
        return figures.fig_particles(_runs(map_name, ("fused",)), None, base)
    if kind == "cdf":
        return figures.fig_cdf(_runs(map_name, ("gnss", "fused")), base)
    if kind == "per_path":
        per_path = pd.DataFrame({"path": ["path1"] * 2, "method": ["gnss", "fused"],
                                 "euclid_mean_m": [9.0, 4.0]})
        return figures.fig_per_path(per_path, base)
    medians = pd.DataFrame({"subset": ["paper6"] * 3, "session": list("abc"), "gnss": [10.0, 12, 20],
                            "paper": [5.0, 6, 30], "fused": [4.0, 5, 6]})
    return figures.fig_session_medians(medians, base, 1.5)


@pytest.fixture(autouse=True)
def _close_figures():
    yield
    plt.close("all")


KINDS = ("reliability", "tracks", "particles", "cdf", "per_path", "session_medians")


@pytest.mark.parametrize("map_name", ["osm", LONG_MAP])
@pytest.mark.parametrize("kind", KINDS)
def test_every_title_and_label_lies_inside_its_figure(kind, map_name):
    fig = _figure(kind, map_name)
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    inside = fig.bbox.padded(1.0)  # a pixel of rounding
    titles = [t for t in (fig._suptitle, *(ax.title for ax in fig.axes)) if t is not None and t.get_text()]
    assert titles
    for text in titles:
        box = text.get_window_extent(renderer)
        assert inside.x0 <= box.x0 and box.x1 <= inside.x1 and box.y1 <= inside.y1, (kind, text.get_text())
    for text in fig.findobj(Text):  # legends, axis labels, notes: none cut by a side either
        if text.get_visible() and text.get_text().strip() and not text.get_clip_on():
            box = text.get_window_extent(renderer)
            assert inside.x0 <= box.x0 and box.x1 <= inside.x1, (kind, text.get_text())
    if map_name == LONG_MAP:  # wrapped, not cut: the whole map name is there
        assert LONG_MAP in "".join(t.get_text().replace("\n", "") for t in titles)


def test_a_title_that_fits_is_left_on_one_line():
    fig = figures.fig_cdf(_runs("osm", ("gnss", "fused")), _base("osm"))
    assert "\n" not in fig._suptitle.get_text()


def test_the_reliability_title_keeps_its_configuration_on_a_line_of_its_own():
    fig = figures.fig_reliability(_reliability_rows(), _base("osm"))
    assert "(jaywalk weight w = 0.4, map 'osm')" in fig._suptitle.get_text().splitlines()


def _fails(capsys, argv: list[str], needle: str) -> str:
    assert localize_main(argv) == 2
    err = capsys.readouterr().err
    assert needle in err and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    return err


@pytest.fixture
def walks(tmp_path) -> Path:
    """A folder holding one session folder (refused before anything is read from it)."""
    folder = tmp_path / "walks" / "walk1"
    folder.mkdir(parents=True)
    (folder / "waypoints.csv").write_text("t,lat,lon\n")
    return folder.parent


def test_a_session_given_twice_is_refused(tmp_path, capsys, walks):
    out = tmp_path / "report"
    session = walks / "walk1"
    again = tmp_path / "walks" / ".." / "walks" / "walk1"
    for given in ([session, session], [walks, session], [session, again]):
        err = _fails(capsys, ["evaluate", *map(str, given), "--maps", str(MAP), "--methods", "gnss",
                              "-o", str(out)], "the same session folder is given twice")
        assert "walk1" in err
    assert not out.exists()


def test_a_map_given_twice_is_named_as_such_not_blamed_on_map_names(tmp_path, capsys, walks):
    out = tmp_path / "report"
    same = str(MAP.parent / ".." / MAP.parent.name / MAP.name)
    err = _fails(capsys, ["evaluate", str(walks), "--maps", str(MAP), same, "-o", str(out)],
                 "the same map is given twice")
    assert "--map-names" not in err
    other = tmp_path / "other" / MAP.name  # another file of the same name: a name is needed
    other.parent.mkdir()
    shutil.copy(MAP, other)
    _fails(capsys, ["evaluate", str(walks), "--maps", str(MAP), str(other), "-o", str(out)],
           "name the maps with --map-names")
    _fails(capsys, ["evaluate", str(walks), "--maps", str(MAP), str(other), "--map-names", "a", "a",
                    "-o", str(out)], "--map-names: give one distinct name per map")


def test_evaluate_says_one_session_and_one_run_in_the_singular(tmp_path, capsys):
    session = tmp_path / "path3-s1"
    assert localize_main(["simulate", "--route", "path3", "--seed", "1", "--map", str(MAP),
                          "-o", str(session)]) == 0
    capsys.readouterr()
    out = tmp_path / "report"
    assert localize_main(["evaluate", str(session), "--maps", str(MAP), "--methods", "gnss",
                          "--jaywalk-weights", "0.4", "--workers", "1", "-o", str(out)]) == 0
    assert capsys.readouterr().out.strip() == f"{out}: report over 1 session, 1 run"


@pytest.mark.parametrize("seeds", [1, 3])
def test_the_interval_note_counts_the_sessions_of_a_route(monkeypatch, seeds):
    monkeypatch.setattr(suite_report, "subset_intervals", lambda *a, **k: pd.DataFrame({"value": [0.5]}))
    monkeypatch.setattr(suite_report, "map_intervals", lambda *a, **k: pd.DataFrame())
    monkeypatch.setattr(suite_report, "reliability_rows", lambda *a, **k: [])
    monkeypatch.setattr(suite_report, "confidence_table", lambda *a, **k: None)
    monkeypatch.setattr(suite_report, "interval_table", lambda frame, title, note: note)
    tables, _ = suite_report.interval_tables([], SuiteConfig(subsets=("paper6",), seeds=seeds))
    note = tables["subsets"]
    assert "three" not in note
    if seeds == 1:
        assert "walked once" in note and "resampled as independent" not in note
    else:
        assert f"The {seeds} sessions of a route are resampled as independent" in note


def _gappy_session(meta: dict) -> Session:
    t = np.r_[0.0, 1.0, 2.0, 9.0, 10.0]  # one 7 s gap
    gnss = pd.DataFrame({"t": t, "lat": 37.79, "lon": -122.40, "accuracy_m": 5.0})
    return Session("walk", source="walks/walk", gnss=gnss, meta=meta)


def test_gnss_gaps_of_a_simulated_walk_are_info_and_of_a_real_one_a_warning(caplog):
    logger = "curbside.localize.input_warnings"
    with caplog.at_level(logging.INFO, logger=logger):
        report_gnss_holds(_gappy_session({"simulation": {"route": "path3"}}), RunConfig())
        report_gnss_holds(_gappy_session({}), RunConfig())
    levels = [(r.levelno, "GNSS gap" in r.getMessage()) for r in caplog.records if r.name == logger]
    assert levels == [(logging.INFO, True), (logging.WARNING, True)]


def test_osmseg_show_prints_what_it_wrote(tmp_path, capsys, test_data):
    crossroads = test_data / "maps" / "crossroads.geojson"
    for name in ("map.png", "map.html"):
        out = tmp_path / name
        assert osmseg_main(["show", str(crossroads), "-o", str(out)]) == 0
        printed = capsys.readouterr().out.strip()
        assert printed.startswith(f"wrote {out} ({crossroads}") and printed.endswith("MB)"), printed


def test_the_scale_bar_box_fits_its_bar_and_label():
    fig = Figure(figsize=(12, 10), dpi=100)
    ax = fig.add_axes((0.01, 0.01, 0.98, 0.94))
    plot_map(read_map(MAP), ax)
    canvas = FigureCanvasAgg(fig)  # a Figure made directly, as osmseg's save_png makes it
    canvas.draw()
    renderer = canvas.get_renderer()
    label = next(t for t in fig.findobj(Text) if t.get_text().endswith(" m") and t.get_text()[0].isdigit())
    text = label.get_window_extent(renderer)
    boxes = [p for p in fig.findobj(Patch) if p is not ax.patch]
    boxes += [a.patch for a in ax.artists if hasattr(a, "patch")]
    behind = [b.get_window_extent(renderer) for b in boxes
              if b.get_window_extent(renderer).contains(*text.get_points().mean(axis=0))]
    box = min(behind, key=lambda b: b.width * b.height)
    assert box.height <= 3.0 * text.height, (box.height, text.height)


def test_ipin_trials_without_ipin_is_refused_not_ignored(tmp_path, capsys, walks):
    out = tmp_path / "report"
    _fails(capsys, ["evaluate", str(walks), "--maps", str(MAP), "--ipin-trials", "2", "-o", str(out)],
           "--ipin-trials: chooses trials of --ipin H5, which is not given")
    assert not out.exists()
