"""The shared configuration checks of pe_drake.config: finite numbers, fractions, YAML loading."""

# No ``from __future__ import annotations``: yaml_load_typed reads the schema's field types.
import dataclasses

import numpy as np
import pytest

from pe_drake.config import check_finite, check_fraction
from pe_drake.yaml_check import load_yaml_typed
from pe_drake.exceptions import ConfigError


@dataclasses.dataclass
class _Schema:
    rate_hz: float = 1.0
    names: list[str] = dataclasses.field(default_factory=list)


@pytest.mark.parametrize(
    "value, kwargs, match",
    [
        ("a", {}, "x must be a number, got 'a'"),
        (True, {}, "x must be a number"),
        (float("nan"), {}, "x must be a finite number"),
        (np.inf, {}, "x must be a finite number"),
        (0.0, {"positive": True}, "x must be positive, got 0.0"),
        (-1, {"nonneg": True}, "x must be non-negative, got -1"),
    ],
)
def test_check_finite_refuses(value, kwargs, match):
    with pytest.raises(ConfigError, match=match):
        check_finite("x", value, **kwargs)


def test_check_finite_and_fraction_accept_and_return_floats():
    assert check_finite("x", np.int64(3), positive=True) == 3.0
    assert isinstance(check_finite("x", np.float32(0.5)), float)
    assert check_finite("x", 0, nonneg=True) == 0.0
    assert check_fraction("f", 1) == 1.0
    for bad in (0.0, 1.5):
        with pytest.raises(ConfigError, match="f must"):
            check_fraction("f", bad)


def test_load_yaml_typed(tmp_path):
    good = tmp_path / "good.yaml"
    good.write_text("rate_hz: 2.5\n")
    assert load_yaml_typed(good, _Schema) == _Schema(rate_hz=2.5)
    assert load_yaml_typed(good, _Schema, _Schema(names=["a"])) == _Schema(rate_hz=2.5, names=["a"])
    with pytest.raises(ConfigError, match=r"widget file '.*none.yaml' does not exist"):
        load_yaml_typed(tmp_path / "none.yaml", _Schema, what="widget")
    for text in ("bogus: 1\n", "rate_hz: [1, 2]\n", "rate_hz: [1, 2\n", "- a\n"):
        bad = tmp_path / "bad.yaml"
        bad.write_text(text)
        with pytest.raises(ConfigError, match=r"widget file '.*bad.yaml' does not match the widget format"):
            load_yaml_typed(bad, _Schema, what="widget")


def test_a_bad_value_in_a_config_file_names_the_file_and_line(tmp_path):
    """Value checks run after loading; the error still points at the file and the key's line."""
    from pe_drake.config import load_config

    path = tmp_path / "mine.yaml"
    path.write_text("solver: {max_iterations: 100}\nexcitation:\n  harmonics: 5\n  criterion: softcond\n")
    with pytest.raises(ConfigError) as err:
        load_config(path)
    message = str(err.value)
    assert f"config file '{path}', line 4: excitation.criterion 'softcond'" in message
    assert "did you mean 'soft_cond'?" in message
    path.write_text("excitation:\n  amplitude: -1\n")
    with pytest.raises(ConfigError, match=r"mine.yaml', line 2: excitation.amplitude"):
        load_config(path)


@pytest.mark.parametrize("value, kind", [("true", "bool"), ("on", "bool"), ("1", "int"), ("0.5", "float")])
def test_an_unquoted_non_string_in_a_string_field_says_to_quote_it(tmp_path, value, kind):
    """`control.model: true` is YAML's boolean: the error says so and what to write, not a Python type."""
    from pe_drake.simulation.truth import read_truth_file

    path = tmp_path / "truth.yaml"
    path.write_text(f"control:\n  model: {value}\n")
    with pytest.raises(ConfigError) as err:
        read_truth_file(path)
    message = str(err.value)
    assert f"line 2, key 'control.model': expected a string, got '{value}', which YAML reads as {'an' if kind == 'int' else 'a'} {kind}" in message
    assert f'write it in quotes, "{value}"' in message
    path.write_text('control:\n  model: "true"\n')  # quoted: the string the truth expects
    assert read_truth_file(path)["control"].model == "true"
