"""Every chapter-6 sweep file loads and validates, in full and in quick mode."""

from __future__ import annotations

from pathlib import Path

import pytest

from hil.evaluation.reproduce import ITEMS, default_sweeps_dir, load_item, select_items
from hil.evaluation.sweep_file import load_sweep_file

#: Shipped sweeps that are not chapter-6 items (``hil sweep NAME``; tested with their trial).
OTHER_SWEEPS = ("tank-mc", "scenes")
FILES = sorted(p for p in default_sweeps_dir().glob("*.toml") if p.stem not in OTHER_SWEEPS)


def test_one_file_per_item_and_no_stray_files() -> None:
    assert sorted(p.stem for p in FILES) == sorted(item.id for item in ITEMS)
    assert sorted(p.stem for p in default_sweeps_dir().glob("*.toml")) == sorted(
        [*(item.id for item in ITEMS), *OTHER_SWEEPS]
    )
    assert len(ITEMS) == 13


@pytest.mark.parametrize("path", FILES, ids=[p.stem for p in FILES])
def test_sweep_file_loads_and_states_its_choices(path: Path) -> None:
    spec = load_sweep_file(path)
    assert spec.name == path.stem
    assert spec.trial in ("ch6_receiver", "ch6_fmcw", "ch6_cost")
    assert spec.n_trials >= 9
    # Every file says what it chose where the seed's tables are unknown.
    text = path.read_text(encoding="utf-8")
    assert text.startswith("# ")
    assert len(spec.description) > 80


@pytest.mark.parametrize("item", ITEMS, ids=[i.id for i in ITEMS])
def test_quick_mode_reduces_and_validates(item: object) -> None:
    full, _ = load_item(item, default_sweeps_dir())  # type: ignore[arg-type]
    quick, _ = load_item(item, default_sweeps_dir(), quick=True)  # type: ignore[arg-type]
    assert quick.n_trials < full.n_trials
    assert quick.grid[item.x] == item.quick_grid.get(item.x, full.grid[item.x])  # type: ignore[attr-defined]
    one, _ = load_item(item, default_sweeps_dir(), trials_per_point=1)  # type: ignore[arg-type]
    assert one.n_trials == full.n_points


def test_x_parameter_is_swept_in_every_item() -> None:
    for item in ITEMS:
        spec, _ = load_item(item, default_sweeps_dir())
        assert item.x in spec.grid, item.id


def test_select_items_keeps_table_order_and_refuses_unknown() -> None:
    assert [i.id for i in select_items(["cmp_jifs", "fig6_4_gcas_m"])] == [
        "fig6_4_gcas_m",
        "cmp_jifs",
    ]
    with pytest.raises(Exception, match=r"--items = 'nope' is not allowed: must be items among"):
        select_items(["nope"])
