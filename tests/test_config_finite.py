"""Every number of a run's configuration is finite: ``Infinity`` and ``NaN`` (which Python's JSON reads,
bare or in a string) are refused with the key, from ``--set``, a ``run.json``, Python and the service."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import pytest
from serve_fixtures import TRIAL

from curbside.cli.localize import main
from curbside.configio import parameters
from curbside.errors import CurbsideInputError
from curbside.localize.runconfig import RunConfig, non_finite_keys
from curbside.localize.serve.service import ServiceConfig, TrackingService


@pytest.mark.parametrize("mode", ["fused", "paper"])
def test_every_float_parameter_refuses_infinity_and_nan_naming_it(mode):
    base = RunConfig.for_mode(mode)
    keys = [p.key for p in parameters(base) if "float" in p.kind]
    assert len(keys) > 90
    for key in keys:
        for value in ("Infinity", "-Infinity", "NaN", math.inf, math.nan):
            with pytest.raises(CurbsideInputError) as refused:
                base.with_overrides({key: value})
            # named before a range check of its section (``...: heading_noise_deg must be non-negative``)
            assert str(refused.value) == f"config.{key}: must be a finite number", (key, value)


def test_the_refusal_names_the_key_as_the_service_and_the_cli_write_it():
    with pytest.raises(CurbsideInputError) as refused:
        RunConfig().with_overrides({"filter.gnss.sigma_factor": "Infinity"})
    assert str(refused.value) == "config.filter.gnss.sigma_factor: must be a finite number"
    with pytest.raises(CurbsideInputError, match=r"^config\.fix_lag\.candidates_s\[1\]: must be a finite"):
        RunConfig().with_overrides({"fix_lag.candidates_s": "[1.0, Infinity]"})
    with pytest.raises(CurbsideInputError, match=r"^config\.filter\.motion\.heading_noise_deg: must be"):
        RunConfig().with_overrides({"filter": {"motion": {"heading_noise_deg": math.inf}}})


def test_a_config_built_in_python_is_checked_too():
    config = RunConfig()
    gnss = replace(config.filter.gnss, sigma_factor=math.inf)
    with pytest.raises(CurbsideInputError, match="config.filter.gnss.sigma_factor: must be a finite number"):
        replace(config, filter=replace(config.filter, gnss=gnss))
    assert non_finite_keys(RunConfig.for_mode("paper").to_dict()) == []


def test_localize_run_set_infinity_is_a_usage_error(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["run", TRIAL, "--set", "filter.gnss.sigma_factor=Infinity", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err == "localize: error: config.filter.gnss.sigma_factor: must be a finite number\n"
    assert not out.exists()


@pytest.mark.parametrize("value", [math.inf, -math.inf, math.nan])
def test_a_run_json_with_a_non_finite_number_is_named_with_its_path(tmp_path, capsys, value):
    config = RunConfig().to_dict()
    config["engine"]["max_fix_age_s"] = value
    run_json = tmp_path / "run.json"
    run_json.write_text(json.dumps({"session": TRIAL, "config": config}))  # writes Infinity, NaN
    assert main(["run", "--config", str(run_json), "-o", str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err == (
        f"localize: error: {run_json}: config.engine.max_fix_age_s: must be a finite number\n"
    )


def test_the_services_own_set_may_not_hold_infinity_either(tmp_path, ronin_model):
    config = ServiceConfig(data_dir=tmp_path, overrides={"filter.gnss.outlier_radius_m": "Infinity"})
    with pytest.raises(CurbsideInputError, match="filter.gnss.outlier_radius_m: must be a finite number"):
        TrackingService(config, ronin_model)
