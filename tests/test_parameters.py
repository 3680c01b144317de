"""The parameter listing (``localize parameters``, ``osmseg parameters``, docs/parameters.md)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import pytest

from curbside.cli.localize import main as localize_main
from curbside.cli.osmseg import main as osmseg_main
from curbside.cli.parameters import reference_markdown
from curbside.configio import field_docs, parameters, sections, with_overrides
from curbside.localize.runconfig import RunConfig
from curbside.osmseg.config import SegmentationConfig

DOC = Path(__file__).resolve().parents[1] / "docs" / "parameters.md"


@dataclass(frozen=True)
class _Inner:
    """An inner section.

    Attributes
    ----------
    width_m : float
        How wide,
        in metres (``m``).
    """

    width_m: float = 2.0


@dataclass(frozen=True)
class _Outer:
    """An outer config, with a summary
    over two lines.

    Attributes
    ----------
    a, b
        Shared by :class:`~curbside.configio.Parameter` and ``b``.
    inner
        The inner section.

    Notes
    -----
    not_a_field
        Must not be read as a field.
    """

    a: int = 1
    b: tuple[float, ...] = (1.0, 2.0)
    inner: _Inner = field(default_factory=_Inner)
    undocumented: str = "x"


def test_field_docs_reads_the_attributes_section_only():
    docs = field_docs(_Outer)
    assert docs == {"a": "Shared by `Parameter` and `b`.", "b": "Shared by `Parameter` and `b`.",
                    "inner": "The inner section."}
    assert field_docs(_Inner) == {"width_m": "How wide, in metres (`m`)."}


def test_parameters_flatten_nested_sections_in_field_order():
    listed = parameters(_Outer())
    assert [p.key for p in listed] == ["a", "b", "inner.width_m", "undocumented"]
    assert [p.value for p in listed] == [1, [1.0, 2.0], 2.0, "x"]
    assert listed[1].kind == "tuple[float, ...]"
    assert listed[3].description == ""
    assert sections(_Outer()) == {"": "An outer config, with a summary over two lines.",
                                  "inner": "An inner section."}


@pytest.mark.parametrize("config", [RunConfig(), SegmentationConfig()], ids=["run", "osmseg"])
def test_every_parameter_is_documented_and_settable(config):
    listed = parameters(config)
    undocumented = [p.key for p in listed if not p.description]
    assert not undocumented, f"add these to their class's Attributes section: {undocumented}"
    assert len({p.key for p in listed}) == len(listed)
    # every listed key is one --set accepts, and setting a key to its listed value changes nothing
    assert with_overrides(config, {p.key: p.value for p in listed}) == config


def test_the_paper_column_lists_the_paper_preset():
    paper = {p.key: p.value for p in parameters(RunConfig.for_mode("paper"))}
    assert paper["filter.n_particles"] == 500 and paper["filter.gnss.sigma_factor"] == 1.0
    page = reference_markdown()
    assert "| `filter.n_particles` | `2000` | int | `500` |" in page
    assert "| `seed` | `0` | int | |" in page  # same in both: no paper value


def test_docs_page_is_in_step_with_the_code():
    assert DOC.read_text(encoding="utf-8") == reference_markdown(), (
        "docs/parameters.md is stale: python -m curbside.cli.parameters > docs/parameters.md"
    )


def test_localize_parameters_lists_and_filters(capsys):
    assert localize_main(["parameters", "gnss.sigma"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("filter.gnss.sigma_factor = 0.66  (float)\n    Likelihood sigma")
    assert "filter.n_particles" not in out
    assert localize_main(["parameters", "N_PARTICLES", "--mode", "paper"]) == 0
    assert "filter.n_particles = 500  (int)" in capsys.readouterr().out
    assert localize_main(["parameters", "--markdown", "fix_lag.lag_s"]) == 0
    assert "| `fix_lag.lag_s` | `0.0` | float |" in capsys.readouterr().out


def test_osmseg_parameters_lists_the_build(capsys):
    assert osmseg_main(["parameters", "crosswalk_width"]) == 0
    assert capsys.readouterr().out.startswith("crosswalk_width_m = 3.0  (float)\n    Width of a crosswalk")


def test_a_pattern_that_matches_nothing_is_a_one_line_error(capsys):
    assert localize_main(["parameters", "no_such_thing"]) == 2
    err = capsys.readouterr().err
    assert err == "localize: error: localize parameters: no parameter key contains 'no_such_thing'\n"
