"""The `sitrelax` command: bvh info, bench plumbing, errors as one line."""

import json
import subprocess
import sys

import pytest

from solver.bench import UnknownBenchmarkError, run_benchmarks
from solver.cli import main


def test_bvh_info_json(capsys, cmu_high_sit):
    assert main(["bvh", "info", str(cmu_high_sit), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["joints"] == 31
    assert info["frames"] == 77
    assert info["channels"] == 96
    assert info["profile"] == "cmu"
    assert info["frame_time"] == pytest.approx(1 / 30, rel=1e-5)
    assert info["duration"] == pytest.approx(77 / 30, rel=1e-5)
    assert info["joint_names"][0] == "Hips" and len(info["joint_names"]) == 31
    assert 0.45 < info["root_height_min_m"] < 0.55
    assert 0.95 < info["root_height_max_m"] < 1.05


def test_bvh_info_axis(capsys, axis_standing):
    assert main(["bvh", "info", str(axis_standing), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert (info["joints"], info["frames"], info["channels"]) == (59, 2156, 180)
    assert info["profile"] == "axis_neuron"
    assert info["duration"] == pytest.approx(17.248)


def test_bvh_info_text_and_bundled(capsys):
    assert main(["bvh", "info", "bundled:cmu_75_18_high_sit.bvh"]) == 0
    out = capsys.readouterr().out
    assert "joints      31" in out and "root height 0.499 .. 1.009 m" in out


def test_bvh_list(capsys):
    assert main(["bvh", "list", "--json"]) == 0
    assert "cmu_75_18_high_sit.bvh" in json.loads(capsys.readouterr().out)


def test_errors_are_one_line(capsys, tmp_path):
    bad = tmp_path / "bad.bvh"
    bad.write_text("HIERARCHY\nROOT Hips\n{\n\tOFFSET 0 0\n")
    assert main(["bvh", "info", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"sitrelax: error: {bad}:4: expected 3 numbers after OFFSET, got 2"
    assert main(["bvh", "info", str(tmp_path / "missing.bvh")]) == 2
    assert "No such file or directory" in capsys.readouterr().err
    assert main(["bvh", "info", "bundled:nope.bvh"]) == 2
    assert "No bundled recording 'nope.bvh'" in capsys.readouterr().err


def test_debug_shows_the_exception(tmp_path):
    with pytest.raises(ValueError):
        main(["--debug", "bvh", "info", "bundled:cmu_75_18_high_sit.bvh", "--unit", "furlong"])


def test_console_script_runs():
    out = subprocess.run(
        [sys.executable, "-m", "solver.cli", "bvh", "info", "bundled:cmu_75_18_high_sit.bvh",
         "--json"], capture_output=True, text=True, check=True,
    )
    assert json.loads(out.stdout)["frames"] == 77


def test_bench_rejects_unknown_names():
    with pytest.raises(UnknownBenchmarkError, match="got \\['nope'\\]"):
        run_benchmarks(["nope"])


def test_bench_entry_shape():
    rows = run_benchmarks(["bvh_fk"], repeats=1)
    assert [r["name"] for r in rows] == ["bvh_fk"]
    assert rows[0]["median_s"] > 0 and "speedup" not in rows[0]
