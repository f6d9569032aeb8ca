"""The MPF's `[mpf]` options: at most 25, each a field of `MPFConfig` and a row of the one table
of docs/usage.md ("Options of the MPF"), and `apply_overrides` accepts those and no other key."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import pytest

from tirefilter.errors import ConfigError
from tirefilter.estimators import apply_overrides, mpf_config_for_scenario
from tirefilter.estimators.mpf import MPFConfig
from tirefilter.estimators.mpf.config import OPTIONS, USER_OPTIONS
from tirefilter.scenarios import load_scenario

USAGE = Path(__file__).resolve().parents[1] / "docs" / "usage.md"


def _table_rows() -> dict[str, str]:
    """The option rows of docs/usage.md's table of `[mpf]` options: name -> the row."""
    text = USAGE.read_text()
    start = text.index("### Options of the MPF")
    end = text.index("\n#", start + 1)
    return {m.group(1): m.group(0) for m in re.finditer(r"^\| `(\w+)` \|.*$", text[start:end], re.M)}


def test_at_most_25_options_each_a_field_and_a_row_of_the_table():
    fields = {f.name for f in dataclasses.fields(MPFConfig)}
    assert len(USER_OPTIONS) == len(set(USER_OPTIONS)) <= 25
    assert set(USER_OPTIONS) <= fields
    rows = _table_rows()
    assert set(rows) == set(USER_OPTIONS), set(rows) ^ set(USER_OPTIONS)
    for key, row in rows.items():  # the columns: option, default, unit, what it changes
        cells = [c.strip() for c in re.split(r"(?<!\\)\|", row.strip("|"))]
        assert len(cells) == 4 and all(cells), row
    # the groups of the table are OPTIONS' (one heading row each, in that order)
    text = USAGE.read_text()
    headings = re.findall(r"^\| \*\*(.+?)\*\* \|", text[text.index("### Options of the MPF"):], re.M)
    assert headings[:len(OPTIONS)] == [g.capitalize() for g in OPTIONS]


def test_every_option_is_settable_and_nothing_else():
    """Each option with its default value passes; a field that is no option (a fixed value of the
    method, or what the scenario or log tells the filter) is refused as unknown, the error naming
    the table, the key and the options."""
    cfg = MPFConfig()
    for key in USER_OPTIONS:
        value = getattr(cfg, key)
        assert getattr(apply_overrides(cfg, {key: list(value) if isinstance(value, tuple) else value},
                                       options=USER_OPTIONS), key) == value
    for key in ("gate_warmup", "x0_mean", "init_center", "sample_period", "resample_threshold", "surprise_inflation"):
        with pytest.raises(ConfigError, match="unknown option") as err:
            apply_overrides(cfg, {key: 1.0}, options=USER_OPTIONS)
        assert "--config [mpf]" in str(err.value) and key in str(err.value)
        assert "known: " + ", ".join(sorted(USER_OPTIONS)) in str(err.value)


def test_the_builders_refuse_what_is_no_option():
    with pytest.raises(ConfigError, match=r"gate_warmup.*unknown option \(known: backend, bias0_std"):
        mpf_config_for_scenario(load_scenario("paper-sim"), model="full", particles=10,
                                overrides={"gate_warmup": 0.5})
    cfg = mpf_config_for_scenario(load_scenario("paper-sim"), model="full", particles=10,
                                  overrides={"gate_ay_max": 3.0, "bias_rw": [0.0, 0.0, 0.0]})
    assert cfg.gate_ay_max == 3.0 and cfg.bias_rw == (0.0, 0.0, 0.0)
