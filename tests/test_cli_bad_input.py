"""Bad input to the ``localize`` commands: one line, exit status 2, the file or argument named, nothing
half-written (seeds, ports, RoNIN weights, particle stores, timestamps, the benchmark's folder)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch

from curbside.cli.localize import main
from curbside.errors import CurbsideInputError
from curbside.evaluate import suite, suite_output
from curbside.io import MARKER, note_written
from curbside.localize.particle_store import pack_particles, read_particles, write_particles
from curbside.localize.paths import config_path_for
from curbside.localize.pipeline import resolve_config
from curbside.localize.readers._tidy import tidy_table
from curbside.localize.ronin.infer import load_model
from curbside.localize.ronin.model import RoninConfig, RoninResNet
from curbside.localize.ronin.train import save_weights
from curbside.localize.runconfig import RunConfig
from curbside.localize.session import validate_table
from curbside.osmseg.mapio import read_map, write_map

MAP = Path(__file__).parent / "data" / "evaluate" / "sf-path3.geojson"


def _usage_error(capsys, argv: list[str]) -> str:
    """argparse's refusal of ``argv``: exit 2 and its one line."""
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    return err


def _input_error(capsys, argv: list[str]) -> str:
    """A command's refusal of bad input: exit 2 and one line, no traceback."""
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err and err.startswith("localize: error: ")
    return err


# -- seeds, ports and argparse's prefix ---------------------------------------------------------------


@pytest.mark.parametrize(
    "argv",
    [
        ["run", "walk", "--seed", "-1", "-o", "out"],
        ["run", "walk", "--mode", "gnss", "--seed", "-1", "-o", "out"],
        ["simulate", "--route", "path1", "--seed", "-1", "-o", "out"],
        ["evaluate", "walk", "--maps", "m.geojson", "--seed", "-1", "-o", "out"],
        ["benchmark", "--seed", "-1", "-o", "out"],
    ],
)
def test_a_negative_seed_is_refused_when_parsing(tmp_path, capsys, monkeypatch, argv):
    monkeypatch.chdir(tmp_path)
    err = _usage_error(capsys, argv)
    assert f"localize {argv[0]}: error: argument --seed: must be a non-negative integer, got -1" in err
    assert not (tmp_path / "out").exists()


def test_a_negative_seed_from_set_or_a_run_json_is_bad_input():
    with pytest.raises(CurbsideInputError, match="seed must be a non-negative integer, got -3"):
        resolve_config(RunConfig().with_overrides({"seed": -3}), None)
    with pytest.raises(ValueError, match="seed must be a non-negative integer"):
        RunConfig(seed=-2)
    with pytest.raises(CurbsideInputError, match="got -1"):
        resolve_config(None, "gnss", seed=-1)


@pytest.mark.parametrize("port", ["99999", "0", "-5", "http"])
def test_a_port_outside_1_to_65535_is_refused_when_parsing(capsys, port):
    err = _usage_error(capsys, ["serve", "--port", port])
    assert err.startswith("localize serve: error: argument --port: ")


def test_argument_errors_keep_the_error_prefix_and_run_states_its_weight_range(capsys):
    err = _usage_error(capsys, ["run", "--particles", "abc", "-o", "out"])
    assert err == "localize run: error: argument --particles: not an integer: 'abc'\n"
    with pytest.raises(SystemExit):
        main(["run", "--help"])
    said = " ".join(capsys.readouterr().out.split())
    assert "particle weight in [0, 1] on street surface" in said


# -- RoNIN weights ----------------------------------------------------------------------------------------


@pytest.fixture
def weights(tmp_path) -> Path:
    return save_weights(RoninResNet(RoninConfig.for_arch("compact")), tmp_path / "m.pt")


def _with_config(weights: Path, name: str) -> Path:
    path = weights.parent / name
    shutil.copy(config_path_for(weights), config_path_for(path))
    return path


def test_a_file_that_is_not_weights_is_named_in_one_line(weights):
    bad = _with_config(weights, "bad.pt")
    for content in (b'{"a": 1}', np.random.default_rng(0).bytes(3000), b""):
        bad.write_bytes(content)
        with pytest.raises(CurbsideInputError) as info:
            load_model(bad)
        assert str(info.value) == (
            f"{bad}: not a curbside RoNIN weights file (torch cannot read it as saved tensors)"
        )
    torch.save([1, 2], bad)
    with pytest.raises(CurbsideInputError, match="holds a list, not named tensors"):
        load_model(bad)
    with pytest.raises(CurbsideInputError, match="not a curbside RoNIN weights file .a .json is the config"):
        load_model(config_path_for(weights))


def test_weights_for_another_model_say_what_does_not_fit(weights):
    state = torch.load(weights, weights_only=True)
    other = _with_config(weights, "other.pt")
    first = next(iter(state))
    torch.save({**{k: v for k, v in state.items() if k != first}, "extra.weight": torch.zeros(1)}, other)
    with pytest.raises(CurbsideInputError) as info:
        load_model(other)
    message = str(info.value)
    assert f"missing 1 tensor(s): {first}" in message and "unexpected 1 tensor(s): extra.weight" in message
    assert "\n" not in message and "other.json" in message
    torch.save({**state, first: torch.zeros(3, 3)}, other)
    with pytest.raises(CurbsideInputError, match=rf"1 of another shape: {first} is \(3, 3\), not"):
        load_model(other)


def test_a_config_that_is_not_json_text_is_named(weights):
    config_path_for(weights).write_bytes(np.random.default_rng(1).bytes(500))
    with pytest.raises(CurbsideInputError, match="not a RoNIN config"):
        load_model(weights)


def test_ronin_cli_refuses_a_json_file_as_weights(tmp_path, capsys, weights):
    session = tmp_path / "s"
    session.mkdir()
    t = np.arange(0.0, 2.0, 0.01)
    imu = pd.DataFrame({"t": t, "ax": 0.0, "ay": 0.0, "az": 9.81, "gx": 0.0, "gy": 0.0, "gz": 0.0})
    imu.to_csv(session / "imu.csv", index=False)
    bad = tmp_path / "bad.json"
    bad.write_text('{"not": "weights"}')
    err = _input_error(capsys, ["ronin", str(session), "--weights", str(bad)])
    assert f"{bad}: not a curbside RoNIN weights file" in err
    bad_pt = _with_config(weights, "junk.pt")
    bad_pt.write_bytes(b"\x00\x01 not a pickle")
    err = _input_error(capsys, ["ronin", str(session), "--weights", str(bad_pt)])
    assert f"{bad_pt}: not a curbside RoNIN weights file" in err
    assert not (session / "velocity.csv").exists()


# -- particle stores ------------------------------------------------------------------------------------


def _store(path: Path) -> Path:
    rng = np.random.default_rng(0)
    x, y = rng.normal(size=(4, 30)), rng.normal(size=(4, 30))
    return write_particles(pack_particles(np.arange(4.0), x, y, x.mean(1), y.mean(1), "EPSG:32610"), path)


def test_a_corrupt_particle_store_is_named_in_one_line(tmp_path):
    good = _store(tmp_path / "good.npz").read_bytes()
    cases = {"truncated": good[: len(good) // 2], "zeroed": good[:60] + bytes(200) + good[260:],
             "text": b"hello", "empty": b""}
    for name, content in cases.items():
        path = tmp_path / f"{name}.npz"
        path.write_bytes(content)
        with pytest.raises(CurbsideInputError) as info:
            read_particles(path)
        assert str(info.value).startswith(f"{path}: not a readable particle store"), name
        assert "\n" not in str(info.value)
    with pytest.raises(CurbsideInputError, match="no such file"):
        read_particles(tmp_path / "absent.npz")


def test_a_particle_store_with_malformed_arrays_is_named(tmp_path):
    with np.load(_store(tmp_path / "good.npz")) as npz:
        packed = dict(npz)
    np.savez(tmp_path / "shape.npz", **{**packed, "dx_dm": packed["dx_dm"][:2]})
    np.savez(tmp_path / "type.npz", **{**packed, "dx_dm": np.array("x")})
    np.savez(tmp_path / "keys.npz", **{k: v for k, v in packed.items() if k != "ref_x_m"})
    for name in ("shape", "type", "keys"):
        with pytest.raises(CurbsideInputError, match="an array is missing or malformed"):
            read_particles(tmp_path / f"{name}.npz")


# -- numbers in messages -----------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["gnss", "steps", "waypoints"])
@pytest.mark.parametrize(
    "order, what", [([0.0, 10.0, 10.0], "duplicated"), ([0.0, 20.0, 10.0], "out-of-order")]
)
def test_timestamps_in_messages_are_plain_numbers(kind, order, what):
    table = pd.DataFrame({"t": order, "lat": 37.79, "lon": -122.4, "accuracy_m": 5.0})
    with pytest.raises(CurbsideInputError) as info:
        validate_table(kind, table, f"{kind}.csv")
    assert str(info.value) == f"{kind}.csv: {what} timestamp t=10.0 at data row 3"


def test_conflicting_rows_name_their_timestamp_as_a_plain_number():
    table = pd.DataFrame({"t": [1.0, 2.5, 2.5], "v": [1.0, 2.0, 3.0]})
    with pytest.raises(CurbsideInputError) as info:
        tidy_table(table, "x.csv", ("t", "v"))
    assert str(info.value) == ("x.csv: conflicting rows share timestamp t=2.5: data row 2 and data row 3 "
                               "hold different values")


# -- the benchmark's output folder -----------------------------------------------------------------------


def test_benchmark_refuses_a_folder_it_did_not_write_before_any_work(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(suite, "run_suite", lambda *a, **k: pytest.fail("ran into a user's folder"))
    user = tmp_path / "user"
    user.mkdir()
    (user / "notes.txt").write_text("mine")
    err = _input_error(capsys, ["benchmark", "-o", str(user)])
    assert f"{user}: folder is not empty (1 entry) and was not written by curbside" in err
    (user / "notes.txt").unlink()
    (user / "map.geojson").write_text('{"type": "FeatureCollection", "features": []}')
    err = _input_error(capsys, ["benchmark", "-o", str(user)])
    assert "was not written by curbside" in err
    assert sorted(p.name for p in user.iterdir()) == ["map.geojson"]


def test_benchmark_accepts_its_own_folders(tmp_path):
    marked = tmp_path / "marked"
    marked.mkdir()
    (marked / "sessions").mkdir()
    note_written(marked / "sessions", suite_output.COMMAND)
    assert suite_output.check_suite_folder(marked) == marked
    earlier = tmp_path / "earlier"  # from a version that wrote no marker at the top
    (earlier / "sessions").mkdir(parents=True)
    (earlier / "report").mkdir()
    write_map(read_map(MAP), earlier / "map.geojson")
    assert suite_output.check_suite_folder(earlier) == earlier
    (earlier / "map-datasf.geojson").write_text("{}")  # not curbside's
    with pytest.raises(CurbsideInputError, match="not written by curbside"):
        suite_output.check_suite_folder(earlier)
    assert suite_output.check_suite_folder(earlier, overwrite=True) == earlier


def test_a_users_map_in_the_benchmark_folder_is_never_taken_for_its_own(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "map.geojson").write_text('{"type": "FeatureCollection", "features": []}')
    with pytest.raises(CurbsideInputError, match="map.geojson: was not written by curbside"):
        suite_output.benchmark_maps(out, None, None)


@pytest.mark.parametrize("bad_map", ["nope.geojson", "bad.geojson"])
def test_benchmark_with_a_bad_map_leaves_no_folder(tmp_path, capsys, bad_map):
    (tmp_path / "bad.geojson").write_text("{not json")
    out = tmp_path / "bm"
    err = _input_error(capsys, ["benchmark", "--map", str(tmp_path / bad_map), "-o", str(out)])
    assert bad_map in err
    assert not out.exists()


def test_a_benchmark_failing_before_it_writes_removes_the_folder_it_made(tmp_path, monkeypatch):
    def refuse(*args, **kwargs):
        raise CurbsideInputError("tile.topojson", "not a DataSF tile")

    monkeypatch.setattr(suite, "benchmark_maps", refuse)
    out = tmp_path / "bm"
    with pytest.raises(CurbsideInputError):
        suite.run_suite(out, suite.SuiteConfig(subsets=("open",)))
    assert not out.exists()
    out.mkdir()  # a folder that was there before stays
    with pytest.raises(CurbsideInputError):
        suite.run_suite(out, suite.SuiteConfig(subsets=("open",)))
    assert json.loads((out / MARKER).read_text())["command"] == suite_output.COMMAND


# -- messages that name what the user gave ------------------------------------------------------------


def test_custom_route_options_with_a_named_route_are_refused(tmp_path, capsys):
    argv = ["simulate", "--route", "path1", "--length-m", "50", "-o", str(tmp_path / "s")]
    err = _input_error(capsys, argv)
    assert "--route path1" in err and "--length-m" in err and "custom" in err
    err = _usage_error(capsys, ["simulate", "--route", "custom", "--crossings", "-1", "-o", "out"])
    assert "--crossings" in err


def test_a_start_pose_off_the_map_names_the_trial_as_given_not_a_meta_json(tmp_path, capsys):
    from serve_fixtures import TRIAL

    err = _input_error(capsys, ["run", TRIAL, "--map", str(MAP), "-o", str(tmp_path / "run")])
    assert f"{TRIAL}: start pose" in err and "meta.json" not in err
    assert not (tmp_path / "run").exists()


def test_a_velocity_source_that_needs_the_imu_says_so(tmp_path, capsys):
    session = tmp_path / "walk"
    session.mkdir()
    velocity = {"t": [0.0, 1.0], "ve": [1.0, 1.0], "vn": [0.0, 0.0]}
    fixes = {"t": [0.0, 1.0], "lat": [37.79, 37.79], "lon": [-122.40, -122.40], "accuracy_m": [5.0, 5.0]}
    pd.DataFrame(velocity).to_csv(session / "velocity.csv", index=False)
    pd.DataFrame(fixes).to_csv(session / "gnss.csv", index=False)
    err = _input_error(capsys, ["run", str(session), "--velocity-source", "pdr", "-o", str(tmp_path / "run")])
    assert "no imu.csv: --velocity-source pdr needs it" in err
