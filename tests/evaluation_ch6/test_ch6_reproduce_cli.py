"""``hil reproduce`` on a reduced set: figures, CSV tables and report.md; bad input exits 2."""

from __future__ import annotations

import csv
import re
from pathlib import Path

import pytest

from hil.cli.main import main

SUBSET = "sim01_codeword_map,cmp_fmcw,fig5_15_cost"


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[int, Path, str]:
    out = tmp_path_factory.mktemp("repro") / "run"
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        status = main(["reproduce", "--quick", "--out", str(out), "--items", SUBSET,
                       "--serial", "--quiet", "--trials-per-point", "1"])  # fmt: skip
    return status, out, buf.getvalue()


@pytest.mark.slow
def test_quick_subset_writes_figures_tables_and_report(quick_run: tuple[int, Path, str]) -> None:
    status, out, printed = quick_run
    assert status == 0
    assert re.search(r"reproduce: 3 item\(s\), 10 trials \(0 failed\)", printed)
    for item in SUBSET.split(","):
        assert (out / item / "results.jsonl").is_file()
        assert (out / "tables" / f"{item}.csv").is_file()
    figures = sorted(p.name for p in (out / "figures").glob("*.png"))
    assert figures == [
        "cmp_fmcw_bias.png",
        "fig5_15_cost_cost.png",
        "sim01_codeword_map_detection.png",
        "sim01_codeword_map_map_p0.png",
        "sim01_codeword_map_rmse.png",
    ]
    report = (out / "report.md").read_text(encoding="utf-8")
    assert "QUICK" in report
    links = re.findall(r"\]\(([^)]+)\)", report)
    assert len(links) == 8  # five figures, three tables
    for link in links:
        assert (out / link).is_file(), link


@pytest.mark.slow  # shares the quick reproduce run above
def test_tables_hold_pooled_values(quick_run: tuple[int, Path, str]) -> None:
    _, out, _ = quick_run
    with (out / "tables" / "fig5_15_cost.csv").open(encoding="utf-8") as fh:
        cost = list(csv.DictReader(fh))
    assert [int(r["m_hops"]) for r in cost] == [5, 10, 29]
    assert [float(r["direct_bank_mults"]) for r in cost] == [5440000.0, 10880000.0, 31552000.0]
    with (out / "tables" / "sim01_codeword_map.csv").open(encoding="utf-8") as fh:
        (row,) = list(csv.DictReader(fh))
    assert float(row["pd"]) > 0.8 and float(row["crlb_range_m"]) > 0
    with (out / "tables" / "cmp_fmcw.csv").open(encoding="utf-8") as fh:
        fm = {(r["family"], float(r["speed_mps"])): r for r in csv.DictReader(fh)}
    saw = fm[("fmcw-saw", 10.0)]
    assert abs(float(saw["range_bias_m"]) - float(saw["predicted_saw_bias_m"])) < 1.0
    assert abs(float(fm[("fmcw-tri", 10.0)]["range_bias_m"])) < 0.5


@pytest.mark.slow
def test_existing_folder_needs_resume(
    quick_run: tuple[int, Path, str], capsys: pytest.CaptureFixture[str]
) -> None:
    _, out, _ = quick_run
    args = ["reproduce", "--quick", "--out", str(out), "--items", "fig5_15_cost", "--serial",
            "--quiet", "--trials-per-point", "1"]  # fmt: skip
    assert main(args) == 2
    assert "pass --resume to continue that sweep" in capsys.readouterr().err
    assert main([*args, "--resume"]) == 0


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--items", "fig9_9"], "--items = 'fig9_9' is not allowed: must be items among"),
        (["--items", " , "], "--items = ' , ' is not allowed"),
        (["--trials-per-point", "0"], "--trials-per-point = 0 is not allowed: must be an integer"),
        (["--workers", "0"], "--workers = 0 is not allowed: must be an integer in 1.."),
        (
            ["--sweeps", "/nonexistent"],
            "--sweeps = '/nonexistent' is not allowed: must be a folder",
        ),
    ],
)
def test_bad_input_exits_2_with_a_clear_message(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str], message: str
) -> None:
    status = main(["reproduce", "--quick", "--out", str(tmp_path / "x"), "--quiet", *extra])
    assert status == 2
    err = capsys.readouterr().err
    assert err.startswith("hil reproduce: error: ")
    assert message in err
    assert not (tmp_path / "x" / "report.md").exists()


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--no-such-option"], "unrecognized arguments: --no-such-option"),
        (["--workers", "two"], "argument --workers: invalid int value: 'two'"),
        ([], "the following arguments are required: --out"),
    ],
)
def test_bad_option_is_a_usage_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], message: str
) -> None:
    with pytest.raises(SystemExit) as info:
        main(["reproduce", *argv] + (["--out", str(tmp_path)] if argv else []))
    assert info.value.code == 2
    assert message in capsys.readouterr().err
