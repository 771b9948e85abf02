"""Every registered receiver names its options through one classmethod, ``option_names()``,
and an experiment file's ``[receiver] options`` are checked against it: the same tests run on
each receiver of the registry, so a new one cannot be left out of the check."""

from __future__ import annotations

import inspect
from pathlib import Path
from typing import Any

import pytest

from hil.estimation.gcas import GcasReceiver
from hil.estimation.gcas.options import OPTION_NAMES
from hil.estimation.option_types import OptionNames
from hil.estimation.registry import RECEIVERS, check_receiver_options, receiver_class
from hil.experiments.experiment import DEFAULT_EXPERIMENT

from .conftest import one_line_error

#: A value for each option that no constructor declares (an input stage's).
_STAGE_EXAMPLES: dict[str, Any] = {"background": "simulated", "still_periods": 4}


def _example(cls: Any, option: str) -> Any:
    """A value the option accepts: its default in the receiver's or GCAS's constructor."""
    for owner in (cls, GcasReceiver):
        param = inspect.signature(owner.__init__).parameters.get(option)
        if param is not None and param.default is not inspect.Parameter.empty:
            return param.default
    return _STAGE_EXAMPLES[option]


def _experiment(tmp_path: Path, receiver: str, options: str) -> Path:
    text = DEFAULT_EXPERIMENT.replace('name = "gcas-bg"', f'name = "{receiver}"')
    text = text.replace('options = { background = "simulated" }', f"options = {{ {options} }}")
    assert f'name = "{receiver}"' in text and f"options = {{ {options} }}" in text
    path = tmp_path / "exp.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("name", RECEIVERS)
def test_every_option_a_receiver_names_is_accepted(name: str) -> None:
    cls = receiver_class(name)
    names = cls.option_names()
    assert isinstance(names, OptionNames) and names.all, name
    for option in sorted(names.all):
        check_receiver_options(name, {option: _example(cls, option)})
    check_receiver_options(name, {option: _example(cls, option) for option in names.all})


@pytest.mark.parametrize("name", RECEIVERS)
def test_an_experiment_file_s_unknown_receiver_option_is_refused_by_name(
    name: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    experiment = _experiment(tmp_path, name, "not_an_option = 1")
    known = ", ".join(sorted(receiver_class(name).option_names().all))
    assert one_line_error(capsys, ["tank-run", str(experiment)]) == (
        "hil tank-run: error: receiver.options.not_an_option = 1 is not allowed: must be an"
        f" option of the {name} receiver: {known}; check its spelling, or choose the receiver"
        " it belongs to"
    )


@pytest.mark.parametrize("name", RECEIVERS)
def test_an_option_of_the_wrong_type_is_refused_by_name(
    name: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # A table where every option takes a number, a string or a flag.
    names = receiver_class(name).option_names()
    option = sorted(names.all - {"background"})[0]
    experiment = _experiment(tmp_path, name, f"{option} = {{ x = 1 }}")
    err = one_line_error(capsys, ["tank-run", str(experiment)])
    assert err.startswith(
        f"hil tank-run: error: receiver.options.{option} = {{'x': 1}} is not allowed: must be "
    ), err
    assert f"(a {name} option)" in err, err


def test_receivers_built_on_gcas_take_its_options_and_their_stage_s() -> None:
    gcas = frozenset(OPTION_NAMES)
    assert receiver_class("gcas").option_names() == OptionNames(gcas)
    assert receiver_class("gcas-mti").option_names() == OptionNames(frozenset(), gcas)
    assert receiver_class("gcas-still").option_names() == OptionNames(
        frozenset({"still_periods"}), gcas
    )
    assert receiver_class("gcas-bg").option_names() == OptionNames(
        frozenset({"background", "range_readout", "max_spread_s"}), gcas
    )
    assert receiver_class("fmcw").option_names() == OptionNames(
        frozenset({"speed_mode", "edge_fraction"})
    )


def test_the_common_settings_are_one_set_wherever_they_are_named() -> None:
    # hil estimate's flags, replay's recorded defaults and make_receiver's keyword arguments
    # name the same four settings: a fifth added to one and not the others fails here.
    import inspect

    from hil.cli.estimate import COMMON_OPTIONS
    from hil.estimation.registry import make_receiver
    from hil.recording.records import COMMON_SETTINGS

    keywords = {
        name
        for name, p in inspect.signature(make_receiver).parameters.items()
        if p.kind is inspect.Parameter.KEYWORD_ONLY
    }
    assert keywords == {"sound_speed_mps", "max_speed_mps", "max_range_m", "m_hops"}
    assert set(COMMON_OPTIONS) == keywords
    assert {"sound_speed_mps", *COMMON_SETTINGS} == keywords
