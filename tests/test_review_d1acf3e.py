"""Regressions found reviewing the commits after d1acf3e: each test failed before its fix."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from curbside.errors import CurbsideInputError
from curbside.osmseg import overpass

ROOT = Path(__file__).resolve().parents[1]


def test_osmium_lower_bound_has_what_the_code_uses():
    # pyosmium 3.7 has neither osmium.FileProcessor (reader.py) nor SimpleWriter as a context manager
    # (overpass.write_osm_file): with it installed, every map build failed with an internal error.
    (major,) = re.findall(r'^\s*"osmium>=(\d+)', (ROOT / "pyproject.toml").read_text(), re.MULTILINE)
    assert int(major) >= 4


@pytest.mark.parametrize(("lat", "lon"), [(95.0, -122.4), (37.7, 181.0), (-90.5, 0.0)])
def test_overpass_node_off_the_globe_is_refused_not_read_as_no_data(lat, lon):
    # Before: accepted (and cached); the reader then dropped the node as missing and the build said
    # "no OSM buildings or highways in bbox", or warned that "overpass-answer.osm.pbf was cut".
    node = {"type": "node", "id": 7, "lat": lat, "lon": lon}
    assert overpass.element_problem(node) == "node 7 without its coordinates (lat, lon)"
    with pytest.raises(CurbsideInputError, match="Overpass sent node 7 without its coordinates"):
        overpass._overpass_json("overpass", b'{"elements": [%s]}' % str(node).replace("'", '"').encode())


def test_overpass_node_on_the_edge_of_the_globe_is_accepted():
    assert overpass.element_problem({"type": "node", "id": 1, "lat": -90, "lon": 180.0}) is None


@pytest.mark.skipif(sys.platform == "win32", reason="SIGINT to itself is POSIX")
def test_ctrl_c_is_held_while_blocked_though_another_thread_would_take_it():
    # Before: only the main thread's signal mask was set, so a Ctrl-C went to another thread (tqdm's
    # monitor, present whenever the progress bar shows) and interrupted the killing of the workers.
    child = textwrap.dedent(
        """
        import os, signal, threading, time
        from curbside.evaluate import dask_cluster

        threading.Thread(target=threading.Event().wait, daemon=True).start()
        try:
            with dask_cluster.ctrl_c_blocked():
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(0.3)
                print("held", flush=True)
        except KeyboardInterrupt:
            print("raised after", flush=True)
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
        """
    )
    done = subprocess.run([sys.executable, "-c", child], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["held", "raised", "after"], done.stdout


def _file_sha256(path: Path) -> str:
    import hashlib

    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_replay_of_an_earlier_run_json_with_own_weights_does_not_warn_of_other_weights(tmp_path):
    # run.json before 42c8995 recorded the whole config file's digest; comparing it with the model
    # fields' digest said "the RoNIN weights changed" on every such replay, the files untouched.
    from curbside.cli.run_replay import changed_inputs

    weights = tmp_path / "mine.pt"
    weights.write_bytes(b"tensors")
    config = weights.with_suffix(".json")
    config.write_text(json.dumps({"window": 200, "extra": {"trained": "here"}}))
    earlier = {"session_sha256": {}, "ronin_weights": {
        "path": str(weights), "sha256": _file_sha256(weights), "config_sha256": _file_sha256(config)}}
    assert changed_inputs(earlier, {"session_sha256": {}}, None, weights) == []
    config.write_text(json.dumps({"window": 100, "extra": {"trained": "here"}}))
    assert changed_inputs(earlier, {"session_sha256": {}}, None, weights) == [f"the RoNIN weights {weights}"]


@pytest.mark.parametrize("shipped", ["curbside/localize/ronin/weights/ronin_compact",
                                     "benchmarks/weights/ronin_ms_only"])
def test_replay_of_a_run_json_made_before_the_shipped_configs_got_their_provenance(tmp_path, shipped):
    # 3fdb898 added provenance to the shipped configs (model fields and tensors unchanged): a run.json
    # made before recorded the earlier file's digest, and its replay warned of other weights.
    from curbside.cli.run_replay import changed_inputs

    weights = ROOT / f"{shipped}.pt"
    before = subprocess.run(["git", "show", f"d1acf3e:{shipped}.json"], cwd=ROOT, capture_output=True)
    if before.returncode:
        pytest.skip("not a git checkout with d1acf3e")
    earlier_config = tmp_path / "earlier.json"
    earlier_config.write_bytes(before.stdout)
    earlier = {"session_sha256": {}, "ronin_weights": {
        "path": str(weights), "sha256": _file_sha256(weights), "config_sha256": _file_sha256(earlier_config)}}
    assert changed_inputs(earlier, {"session_sha256": {}}, None, weights) == []


@pytest.mark.skipif(shutil.which("openssl") is None, reason="needs openssl to make a certificate")
def test_a_tls_scheduler_that_dask_reaches_is_not_refused(tmp_path):
    # The --scheduler probe connected without dask's TLS settings: a tls:// scheduler that a Client
    # reaches with them was refused ("TLS expects a `ssl_context` argument").
    import dask
    from distributed import LocalCluster
    from distributed.security import Security

    from curbside.evaluate import dask_cluster

    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", str(key), "-out",
                    str(cert), "-days", "1", "-subj", "/CN=localhost", "-addext",
                    "subjectAltName=DNS:localhost,IP:127.0.0.1"], check=True, capture_output=True, timeout=60)
    tls = "distributed.comm.tls"
    config = {f"{tls}.ca-file": str(cert)}
    for role in ("scheduler", "worker", "client"):
        config |= {f"{tls}.{role}.cert": str(cert), f"{tls}.{role}.key": str(key)}
    with dask.config.set(config):
        cluster = LocalCluster(n_workers=0, processes=False, protocol="tls://", security=Security(),
                               dashboard_address=":0", scheduler_kwargs={"dashboard": False})
        try:
            dask_cluster.check_scheduler(cluster.scheduler_address)
        finally:
            cluster.close()
