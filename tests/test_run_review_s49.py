"""Review s49 of ``localize run``, ``localize ronin`` and ``ronin-eval``.

- ``--velocity-source auto`` tracks an IMU that ``localize simulate`` made with PDR, not RoNIN (which
  reads it about 100 deg off), and every warning's advice names only options that exist for the session;
- ``localize ronin`` replaces a ``velocity.csv`` it wrote itself, but not the simulator's (or anyone
  else's) without ``--overwrite``;
- ``localize run`` refuses options that would change nothing (``--mode gnss --lag-s 30``, ...);
- ``ronin-eval`` says that ``--ipin`` takes the whole file, and what the data hold per split.
"""

from __future__ import annotations

import json
import logging
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from curbside.cli.localize import main as localize_main

DATA = Path(__file__).parent / "data"
GPX = str(DATA / "sessions" / "walk.gpx")
H5 = str(DATA / "sessions" / "ipin2023-cut.h5")
START = ["--route", "custom", "--start", "-122.4025", "37.7930", "--length-m", "150", "--crossings", "1",
         "--seed", "3", "--imu"]


def _simulate(folder: Path, *extra: str) -> Path:
    assert localize_main(["simulate", *START, *extra, "-o", str(folder)]) == 0
    return folder


@pytest.fixture(scope="module")
def imu_only(tmp_path_factory) -> Path:
    """A simulated walk with a phone IMU and no ``velocity.csv`` (``--no-velocity``)."""
    return _simulate(tmp_path_factory.mktemp("sim") / "walk", "--no-velocity")


def _warnings(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]


def test_auto_tracks_a_simulated_imu_with_pdr_and_says_so(imu_only, tmp_path, caplog):
    with caplog.at_level(logging.WARNING):
        assert localize_main(["run", str(imu_only), "-o", str(tmp_path / "auto")]) == 0
    info = json.loads((tmp_path / "auto" / "run.json").read_text())
    assert info["velocity_source"] == "pdr"
    [warning] = [m for m in _warnings(caplog) if "simulated" in m]
    assert "--velocity-source auto tracks with PDR instead" in warning
    assert "--velocity-source file" not in warning


def test_ronin_on_a_simulated_imu_runs_with_advice_that_exists(imu_only, tmp_path, caplog):
    with caplog.at_level(logging.WARNING):
        out = tmp_path / "ronin"
        assert localize_main(["run", str(imu_only), "--velocity-source", "ronin", "-o", str(out)]) == 0
    assert json.loads((out / "run.json").read_text())["velocity_source"] == "ronin"
    [warning] = [m for m in _warnings(caplog) if "simulated" in m]
    assert "far off" in warning and "--velocity-source auto or pdr" in warning
    assert "--velocity-source file" not in warning  # the session has no velocity.csv


def test_the_advice_names_velocity_csv_where_the_session_has_one(caplog):
    import pandas as pd

    from curbside.localize.session import Session, warn_if_simulated_imu

    velocity = pd.DataFrame({"t": [0.0, 1.0], "ve": [1.0, 1.0], "vn": [0.0, 0.0]})
    with caplog.at_level(logging.WARNING):
        simulated = Session(name="w", velocity=velocity, meta={"simulation": {}})
        assert warn_if_simulated_imu(simulated, "w/imu.csv")
        assert not warn_if_simulated_imu(Session(name="real", meta={}), "real/imu.csv")
    [warning] = _warnings(caplog)
    assert "velocity.csv" in warning and "--velocity-source auto or file" in warning


def test_own_weights_under_auto_on_a_simulated_imu_are_refused(imu_only, tmp_path, capsys):
    from curbside import settings

    weights = str(settings.ronin_default_weights)
    assert localize_main(["run", str(imu_only), "--ronin-weights", weights, "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "--ronin-weights: not used:" in err and "is simulated" in err and "--velocity-source ronin" in err
    assert not (tmp_path / "o").exists()


def test_ronin_keeps_the_simulators_velocity_unless_overwrite(tmp_path, capsys):
    session = _simulate(tmp_path / "walk")
    velocity = session / "velocity.csv"
    simulated = velocity.read_bytes()
    assert localize_main(["ronin", str(session)]) == 2
    err = capsys.readouterr().err
    assert "written by 'localize simulate', not by localize ronin; pass --overwrite" in err
    assert velocity.read_bytes() == simulated
    assert localize_main(["ronin", str(session), "--overwrite"]) == 0
    assert velocity.read_bytes() != simulated
    assert localize_main(["ronin", str(session)]) == 0  # its own velocity.csv: replaced without --overwrite
    velocity.write_bytes(simulated)  # written again by someone else
    assert localize_main(["ronin", str(session)]) == 2
    assert velocity.read_bytes() == simulated


def test_ronin_replaces_its_own_file_elsewhere(imu_only, tmp_path):
    out = tmp_path / "vel.csv"
    for _ in range(2):
        assert localize_main(["ronin", str(imu_only), "-o", str(out)]) == 0


def test_save_particles_in_gnss_mode_is_warned_of(tmp_path, caplog):
    with caplog.at_level(logging.WARNING):
        argv = ["run", GPX, "--mode", "gnss", "--save-particles", "-o", str(tmp_path / "o")]
        assert localize_main(argv) == 0
    assert any("--save-particles: no particles.npz: --mode gnss" in m for m in _warnings(caplog))
    assert not (tmp_path / "o" / "particles.npz").exists()


#: (argv after ``localize``, what the error line says).
REFUSED = [
    (["run", GPX, "--mode", "gnss", "--lag-s", "30", "-o", "out"], "--lag-s: not used: --mode gnss"),
    (["run", GPX, "--mode", "gnss", "--unseen-velocity", "on", "-o", "out"],
     "--unseen-velocity: not used: --mode gnss reports the fixes as they are"),
    (["run", GPX, "--mode", "gnss", "--lag-s", "5", "--fix-lag", "2", "-o", "out"],
     "--lag-s, --fix-lag: not used: --mode gnss"),
    (["run", GPX, "--mode", "gnss", "--velocity-source", "pdr", "-o", "out"], "--velocity-source: not used"),
    (["run", "--config", "gnss.json", "--lag-s", "30", "-o", "out"], "--lag-s: not used: --mode gnss"),
    (["run", GPX, "--mode", "inertial", "--fix-lag", "2", "-o", "out"],
     "--fix-lag: not used: --mode inertial tracks without GNSS fixes"),
    (["run", GPX, "--unseen-velocity", "on", "--familiar-velocity", "on", "-o", "out"],
     "--familiar-velocity on: not used with --unseen-velocity on"),
    (["run", GPX, "--unseen-velocity", "--familiar-velocity", "-o", "out"],
     "--familiar-velocity auto: not used with --unseen-velocity on"),
    (["run", GPX, "--set", "unseen_velocity.mode=on", "--familiar-velocity", "on", "-o", "out"],
     "--familiar-velocity on: not used with --unseen-velocity on"),
    (["ronin-eval", "--ipin", f"{H5}::TrainingTrial01_repetition01"],
     f"--ipin takes the whole file, not one recording of it ('::TrainingTrial01_repetition01' is not "
     f"supported here): give --ipin {H5}"),
    (["train-ronin", "--ipin", f"{H5}::TrainingTrial01_repetition01", "-o", "w.pt"],
     "--ipin takes the whole file"),
]

_BATCH = textwrap.dedent(
    """
    import contextlib, io, json, sys
    from curbside.cli import localize

    heavy, cases = json.loads(sys.argv[1]), json.loads(sys.argv[2])
    results = []
    for argv in cases:
        err = io.StringIO()
        with contextlib.redirect_stderr(err):
            try:
                status = localize.main(argv)
            except SystemExit as exc:
                status = exc.code
        results.append({"status": status, "stderr": err.getvalue(),
                        "heavy": sorted(name for name in heavy if name in sys.modules)})
    print(json.dumps(results))
    """
)


def test_options_that_change_nothing_are_refused_before_the_heavy_imports(tmp_path):
    from test_cli_startup import HEAVY

    (tmp_path / "gnss.json").write_text(json.dumps({"config": {"mode": "gnss"}, "session": GPX}))
    cases = json.dumps([argv for argv, _ in REFUSED])
    out = subprocess.run([sys.executable, "-c", _BATCH, json.dumps(HEAVY), cases], cwd=tmp_path,
                         capture_output=True, text=True, check=True, timeout=120).stdout
    for (argv, message), result in zip(REFUSED, json.loads(out), strict=True):
        err = result["stderr"]
        assert result["status"] == 2, (argv, err)
        assert err.count("\n") == 1 and err.startswith("localize: error: ") and message in err, (argv, err)
        assert not result["heavy"], (argv, result["heavy"])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["gnss.json"]


def test_options_that_change_something_still_run(imu_only, tmp_path):
    """``off`` and a zero lag say nothing in any mode, so they are accepted with ``--mode gnss``."""
    assert localize_main(["run", GPX, "--mode", "gnss", "--lag-s", "0", "--unseen-velocity", "off",
                          "--familiar-velocity", "off", "--fix-lag", "off", "-o", str(tmp_path / "a")]) == 0
    assert localize_main(["run", str(imu_only), "--unseen-velocity", "on", "--familiar-velocity", "off",
                          "-o", str(tmp_path / "b")]) == 0


def test_ronin_eval_names_what_each_split_holds(capsys):
    assert localize_main(["ronin-eval", "--ipin", H5, "--no-pdr"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("localize: error: ipin2023-cut.h5: no 'test' recordings (--split): the data hold "
                          "2 train, 0 val, 0 test recordings (")
    assert err.rstrip().endswith("give --split train") and err.count("\n") == 1
