"""What a new user gets wrong in an experiment file is named as what it is: a byte order
mark is no error, ``[[tow]]`` is a list of tables (not a missing key), and a misspelt key or
table is answered with the key it resembles, before any "required" message."""

from __future__ import annotations

from pathlib import Path

import pytest

from hil.errors import ConfigError
from hil.experiments.experiment import DEFAULT_EXPERIMENT, load_experiment, parse_experiment


def test_a_utf8_byte_order_mark_is_not_part_of_the_file(tmp_path: Path) -> None:
    path = tmp_path / "bom.toml"
    path.write_bytes(b"\xef\xbb\xbf" + DEFAULT_EXPERIMENT.encode("utf-8"))
    exp = load_experiment(path)
    plain = parse_experiment(DEFAULT_EXPERIMENT)
    assert (exp.name, exp.tow, exp.board_url) == (plain.name, plain.tow, plain.board_url)


def test_an_array_of_tables_for_tow_says_to_write_one_table() -> None:
    text = DEFAULT_EXPERIMENT.replace("\n[tow]\n", "\n[[tow]]\n")
    with pytest.raises(ConfigError) as err:
        parse_experiment(text)
    message = str(err.value)
    assert message.startswith("tow = [{'start_m': -2.0, ")
    assert message.endswith(
        "is not allowed: must be one table (key = value pairs); write [tow] once; [[tow]]"
        " makes a list of tables"
    )


def test_a_misspelt_required_key_is_answered_with_the_key_it_resembles() -> None:
    text = DEFAULT_EXPERIMENT.replace("\nspeed_mps = ", "\nspeed_mp = ")
    with pytest.raises(ConfigError) as err:
        parse_experiment(text)
    assert str(err.value) == (
        "tow.speed_mp = 1.5 is not allowed: must be one of the keys start_m, end_m, speed_mps,"
        " repeats, run_up_m, run_down_m; remove it or fix its spelling (did you mean"
        " speed_mps?) (hil docs tank-run lists every key)"
    )


def test_a_misspelt_table_is_answered_with_the_table_it_resembles() -> None:
    text = DEFAULT_EXPERIMENT.replace("\n[tow]\n", "\n[tw]\n")
    with pytest.raises(ConfigError, match=r"^tw = \{.*\} is not allowed: must be one of the"):
        parse_experiment(text)
    with pytest.raises(ConfigError, match=r"remove it or fix its spelling \(did you mean tow\?\)$"):
        parse_experiment(text)


def test_a_required_key_left_out_is_still_named_as_required() -> None:
    text = DEFAULT_EXPERIMENT.replace("\nspeed_mps = 1.5\n", "\n")
    with pytest.raises(ConfigError) as err:
        parse_experiment(text)
    assert str(err.value) == "tow.speed_mps = None is not allowed: must be a value; it is required"


def test_a_waveform_override_the_family_does_not_read_is_refused() -> None:
    # [waveform] overrides of another family's design would be dropped without a word.
    text = DEFAULT_EXPERIMENT.replace("\n[waveform]\n", "\n[waveform]\noverrides = { order = 5 }\n")
    assert text != DEFAULT_EXPERIMENT
    with pytest.raises(ConfigError) as err:
        parse_experiment(text)
    assert str(err.value) == (
        "waveform.order = 5 is not allowed: must be a setting the random-cyclic family reads; "
        "only three-state read it: drop it, or choose that family"
    )
    three_state = text.replace('family = "random-cyclic"', 'family = "three-state"')
    assert parse_experiment(three_state).waveform.order == 5
