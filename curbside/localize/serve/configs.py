"""A session's run configuration: the service's, with the overrides ``POST /sessions`` carries.

Every refusal is a :class:`~curbside.errors.CurbsideInputError` whose source is the key at fault as the
client wrote it (``config.seed``, ``config.filter.n_particles``), whatever layer refused it (the
``--set`` parser, the config classes, the service's own limits). A JSON ``Infinity`` or ``NaN``, bare or in
a string, is refused by :class:`~curbside.localize.runconfig.RunConfig` itself, as for ``localize run``.
"""

from __future__ import annotations

import contextlib
import json
from collections.abc import Callable
from typing import Any

from curbside.errors import CurbsideInputError
from curbside.localize.filter.config import MapConfig
from curbside.localize.runconfig import RunConfig


def config_key(source: str) -> str:
    """The client's name of the key a config error names: ``--set a.b`` -> ``config.a.b``."""
    source = source.removeprefix("--set ").removeprefix("--")
    return source if source == "config" or source.startswith("config.") else f"config.{source}"


def _check_seed(value: Any) -> None:
    if isinstance(value, str):  # as with_overrides reads it
        with contextlib.suppress(json.JSONDecodeError):
            value = json.loads(value)
    # numpy refuses a negative seed only when the filter starts, when it would be an internal error
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise CurbsideInputError("config.seed", f"must be a non-negative integer, got {value!r}")


def session_config(
    overrides: dict[str, Any],
    base: Callable[[str | None], RunConfig],
    fixed_map: MapConfig,
    max_particles: int,
) -> RunConfig:
    """The run configuration of a new session.

    Parameters
    ----------
    overrides
        ``{"seed": 3, "filter.gnss.sigma_factor": 1.0, "mode": "inertial", ...}`` (``--set`` keys, plus
        ``mode``).
    base
        The service's configuration for a mode (``None``: the service's mode).
    fixed_map
        The service's ``filter.map``: its raster's resolution and segment reach cannot change.
    max_particles
        Largest ``filter.n_particles`` allowed.

    Raises
    ------
    CurbsideInputError
        An unknown key or a refused value, named ``config.KEY``.
    """
    overrides = dict(overrides)
    if "seed" in overrides:
        _check_seed(overrides["seed"])
    try:
        mode_config = base(overrides.pop("mode", None))
        config = mode_config.with_overrides(overrides)
    except CurbsideInputError as exc:
        raise CurbsideInputError(config_key(exc.source), exc.problem) from None
    except (ValueError, TypeError) as exc:  # a check of the config classes, not wrapped by the parser
        raise CurbsideInputError("config", str(exc).splitlines()[0]) from None
    chosen = config.filter.map
    if (chosen.raster_resolution_m, chosen.segment_reach_m) != (
        fixed_map.raster_resolution_m,
        fixed_map.segment_reach_m,
    ):
        raise CurbsideInputError(
            "config.filter.map", "the map raster's resolution and segment reach are the service's"
        )
    if config.filter.n_particles > max_particles:
        raise CurbsideInputError(
            "config.filter.n_particles",
            f"{config.filter.n_particles} exceeds the service's maximum of {max_particles}",
        )
    return config
