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


def test_an_error_with_json_asked_for_is_json_on_standard_output(capsys, tmp_path):
    """A reader of `--json` output gets a failure as a JSON object too (the one line on
    standard error stays)."""
    import json

    bad = tmp_path / "bad.bvh"
    bad.write_text("HIERARCHY\nROOT Hips\n{\n\tOFFSET 0 0\n")
    assert main(["bvh", "info", str(bad), "--json"]) == 2
    out, err = capsys.readouterr()
    assert json.loads(out) == {"error": f"{bad}:4: expected 3 numbers after OFFSET, got 2",
                               "exit_status": 2}
    assert err.startswith("sitrelax: error: ")
    assert main(["fit", str(tmp_path / "none.toml"), "--out", str(tmp_path / "o"),
                 "--json"]) == 2
    assert "No scenario file" in json.loads(capsys.readouterr().out)["error"]


@pytest.mark.parametrize("argv, words", [
    (["fit", "s.toml", "--out", "o", "--unit", "km", "--json"], "argument --unit: invalid choice"),
    (["body", "make", "--out", "body.stl", "--json"], "argument --out: expected a file ending"),
    (["bvh", "info", "--json"], "the following arguments are required: file"),
])
def test_an_option_refused_with_json_asked_for_is_json_on_standard_output(argv, words, capsys,
                                                                          tmp_path, monkeypatch):
    """A value the parser refuses is an error like any other: with `--json` it is also a JSON
    object on standard output (README, "Commands"); without, standard output stays empty."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as stopped:
        main(argv)
    out, err = capsys.readouterr()
    assert stopped.value.code == 2 and words in err
    error = json.loads(out)
    assert error["exit_status"] == 2 and words in error["error"]
    with pytest.raises(SystemExit):
        main([a for a in argv if a != "--json"])
    assert capsys.readouterr().out == ""
    assert list(tmp_path.iterdir()) == []


def test_debug_shows_the_exception(tmp_path):
    with pytest.raises(ValueError):
        main(["--debug", "bvh", "info", "bundled:cmu_75_18_high_sit.bvh", "--unit", "furlong"])



def test_a_reader_that_stops_early_ends_the_command_quietly():
    """`sitrelax ... --json | head`: the reader closes the pipe after a few bytes; the command
    stops without a traceback or an error line, exit status 1."""
    code = ("import argparse, sys; from solver.cli import run; "
            "p = argparse.ArgumentParser(); p.add_argument('--debug', action='store_true'); "
            "p.set_defaults(func=lambda a: print('x' * 1_000_000)); sys.exit(run(p, []))")
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    assert proc.stdout.read(10) == b"x" * 10
    proc.stdout.close()
    err = proc.stderr.read()
    assert proc.wait(60) == 1
    assert b"Traceback" not in err and b"error" not in err, err

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


def test_replay_and_listen_commands(tmp_path):
    import socket
    import time

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    server = subprocess.Popen(
        [sys.executable, "-m", "solver.cli", "capture", "replay",
         "bundled:cmu_75_18_high_sit.bvh", "--tcp", f"127.0.0.1:{port}", "--rate", "10",
         "--wait-client", "--json"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    raw = tmp_path / "session.raw"
    try:
        time.sleep(0.3)
        out = subprocess.run(
            [sys.executable, "-m", "solver.cli", "capture", "listen", f"tcp://127.0.0.1:{port}",
             "--skeleton", "bundled:cmu_75_18_high_sit.bvh", "--frames", "77", "--duration",
             "20", "--json", "--save-raw", str(raw)],
            capture_output=True, text=True, timeout=60, check=True)
    finally:
        sent, _ = server.communicate(timeout=30)
    summary = json.loads(out.stdout)
    assert summary["frames"] == 77 and summary["dropped"] == 0 and summary["corrupt"] == 0
    assert summary["first_index"] == 0 and summary["last_index"] == 76
    assert 200 < summary["fps"] < 400  # 30 fps at 10x
    assert json.loads(sent)["frames_sent"] == 77
    # the raw capture replays to the same frames
    again = subprocess.run(
        [sys.executable, "-m", "solver.cli", "capture", "listen", f"file:{raw}",
         "--skeleton", "bundled:cmu_75_18_high_sit.bvh", "--json"],
        capture_output=True, text=True, timeout=60, check=True)
    assert json.loads(again.stdout)["frames"] == 77


def test_listen_names_a_skeleton_mismatch(tmp_path):
    from capture import read_bvh
    from capture.neuron import encode_binary
    from capture.rawcapture import DATA, RawCaptureWriter
    from capture.stream_layout import StreamLayout

    from .conftest import recording

    axis = read_bvh(recording("axis_neuron_standing_yxz.bvh"))
    payload = StreamLayout(axis.skeleton).to_payload(axis.motion.channels[:5])
    raw = tmp_path / "axis.raw"
    with RawCaptureWriter(raw, source="test", time_origin=0.0) as w:
        for k in range(5):
            w.write(DATA, k * 0.01, encode_binary(payload[k], frame_index=k))
    out = subprocess.run(
        [sys.executable, "-m", "solver.cli", "capture", "listen", f"file:{raw}",
         "--skeleton", "bundled:cmu_75_18_high_sit.bvh"], capture_output=True, text=True)
    assert out.returncode == 2
    assert "31-joint skeleton header" in out.stderr and "got 354 floats" in out.stderr
    assert out.stderr.count("\n") == 1


def test_replay_port_in_use_is_one_line():
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        out = subprocess.run(
            [sys.executable, "-m", "solver.cli", "capture", "replay",
             "bundled:cmu_75_18_high_sit.bvh", "--tcp", f"127.0.0.1:{port}"],
            capture_output=True, text=True, timeout=30)
    assert out.returncode == 2
    assert out.stderr.strip() == f"sitrelax: error: TCP port {port} on 127.0.0.1 is in use"


@pytest.mark.parametrize("command", [["serve"], ["studio", "--out", "studio-out"]])
def test_a_server_on_a_port_in_use_is_one_line(capsys, command, tmp_path, monkeypatch):
    import socket

    from studio.cli import main as sitrelax

    monkeypatch.chdir(tmp_path)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        assert sitrelax([*command, "--port", str(port)]) == 2
    err = capsys.readouterr().err
    assert err.strip().splitlines()[-1] == (
        f"sitrelax: error: Cannot listen on 127.0.0.1:{port}: Address already in use (another "
        f"server holds it: --port picks another, 0 a free one)")
    assert "Traceback" not in err


@pytest.mark.parametrize("argv, words", [
    (["serve", "--port", "70000"], "--port: expected a whole number <= 65535, got '70000'"),
    (["serve", "--time-limit", "nan"], "--time-limit: expected a number, got 'nan'"),
    (["serve", "--max-request-mb", "-1"], "--max-request-mb: expected a number > 0, got '-1'"),
    (["batch", "a.toml", "--out", "o", "--job-time-limit", "-1"],
     "--job-time-limit: expected a number > 0, got '-1'"),
    (["batch", "a.toml", "--out", "o", "--workers", "0"], "--workers: expected a whole number"),
    (["validate", "pressure", "--mu", "0.5", "inf"], "--mu: expected a number, got 'inf'"),
    (["pose", "show", "bvh:bundled:cmu_75_18_high_sit.bvh#frame=39", "--out", "p.png",
      "--pelvis", "1e308"], "--pelvis: expected a number <= 100, got '1e308'"),
    (["pose", "show", "bvh:bundled:cmu_75_18_high_sit.bvh#frame=39", "--out", "p.png",
      "--pelvis", "1", "--lowest", "0"], "not allowed with argument"),
    (["bench", "subdivision", "--repeats", "0"], "--repeats: expected a whole number >= 1"),
    (["bench", "subdivision", "--repeats", "-1"], "--repeats: expected a whole number >= 1"),
    (["body", "make", "--out", "body.stl"],
     "--out: expected a file ending in .obj, .ply, .glb or .png, got 'body.stl'"),
    (["pose", "show", "bvh:bundled:cmu_75_18_high_sit.bvh#frame=39", "--out", "posed.xyz"],
     "--out: expected a file ending in .obj, .ply, .glb or .png, got 'posed.xyz'"),
])
def test_options_out_of_range_are_refused_by_name_before_any_work(argv, words, capsys,
                                                                   tmp_path, monkeypatch):
    from studio.cli import main as sitrelax

    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as stopped:
        sitrelax(argv)
    assert stopped.value.code == 2 and words in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_the_out_suffixes_of_body_make_and_pose_show_are_the_meshes_and_png():
    from solver.cli import OUT_SUFFIXES
    from solver.io.export import MESH_FORMATS

    assert OUT_SUFFIXES == (*MESH_FORMATS, ".png")


@pytest.mark.parametrize("command", [["bvh", "info"], ["pose", "show"]])
def test_unit_help_names_every_unit_the_reader_takes(command, capsys):
    from capture.units import UNITS
    from studio.cli import main as sitrelax

    with pytest.raises(SystemExit):
        sitrelax([*command, "--help"])
    text = " ".join(capsys.readouterr().out.split())
    unit_help = text[text.index("--unit UNIT "):].split(" --", 1)[0]
    assert all(f" {name}," in unit_help or f" {name} " in unit_help for name in UNITS), unit_help


def test_body_make_json_and_files(tmp_path, capsys):
    out = tmp_path / "body.obj"
    assert main(["body", "make", "--weight", "0.7", "--out", str(out), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert {"height_m", "mass_kg", "vertices", "faces", "joints"} <= set(info)
    assert info["vertices"] == 13380 and info["faces"] == 13378 and info["joints"] == 31
    text = out.read_text().splitlines()
    assert sum(line.startswith("v ") for line in text) == 13380
    assert sum(line.startswith("f ") and len(line.split()) == 5 for line in text) == 13378
    import trimesh

    mesh = trimesh.load(out, process=False)
    assert mesh.vertices[:, 1].max() == pytest.approx(info["height_m"], abs=1e-5)
    assert main(["body", "make", "--weight", "2"]) == 2
    assert "weight in [0, 1], got 2.0" in capsys.readouterr().err


def test_pose_show_writes_a_picture_and_a_mesh(tmp_path, capsys):
    import matplotlib.image

    png = tmp_path / "posed.png"
    spec = "bundled:cmu_75_18_high_sit.bvh#frame=39"
    assert main(["pose", "show", spec, "--out", str(png), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["lowest_m"] == pytest.approx(0.0, abs=1e-9)
    assert 0.35 < info["pelvis_height_m"] < 0.6
    image = matplotlib.image.imread(png)
    assert image.shape[:2] == (800, 800)
    drawn = (image[..., :3] < 0.95).any(axis=-1)
    assert 0.05 < drawn.mean() < 0.6  # a figure, not an empty or filled frame
    obj = tmp_path / "posed.obj"
    assert main(["pose", "show", spec, "--out", str(obj), "--pelvis", "0.5"]) == 0
    assert obj.read_text().count("\nf ") == 13378


@pytest.mark.slow
def test_validate_pressure_command(tmp_path, capsys):
    assert main(["validate", "pressure", "--json", "--quick", "--mu", "0.5",
                 "--out", str(tmp_path)]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert {r["pose"] for r in rows} == {"seated", "lying", "reclining"}
    assert {r["reference"] for r in rows} == {"contact programme", "rigid mould"}
    for r in rows:
        assert {"rmse_all", "zero_all", "rmse_loaded", "zero_loaded", "pearson_r", "model_ms",
                "reference_s"} <= set(r)
        if r["model"] == "paper":
            assert r["zero_all"] >= 2 * r["rmse_all"], r
            assert r["crude_all"] >= 2 * r["rmse_all"], r  # (the crude baseline too)
        assert (tmp_path / r["picture"].rsplit("/", 1)[-1]).stat().st_size > 10_000
    assert main(["validate", "pressure", "--quick", "--mu", "0.5",
                 "--reference", "rigid mould"]) == 0
    text = capsys.readouterr().out
    assert "all-zero" in text and "reclining" in text


def test_a_locked_library_and_a_missing_pose_are_one_line(tmp_path, capsys, monkeypatch):
    import fcntl

    import posedb.library

    db = tmp_path / "poses.h5"
    assert main(["db", "import", "bundled:cmu_75_18_high_sit.bvh", "--db", str(db)]) == 0
    capsys.readouterr()
    before = db.read_bytes()
    monkeypatch.setenv("SITRELAX_LOCK_TIMEOUT", "0.3")
    with open(db.with_name(db.name + ".lock"), "a") as held:  # another writer holds the lock
        fcntl.flock(held, fcntl.LOCK_EX)
        assert main(["db", "tag", "cmu_75_18_high_sit", "mine", "--db", str(db)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "locked by another writer" in err
    assert db.read_bytes() == before
    assert main(["pose", "show", "db:nope", "--db", str(db), "--out",
                 str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err
    assert err == f"sitrelax: error: No pose 'nope' in {db}\n"
    assert not (tmp_path / "x.png").exists()


def test_pose_supports_from_the_command_line(tmp_path, capsys):
    """`db pose add --support` takes regions, coarse parts and uses (default a seat's), shows
    the regions, and refuses an unknown name before anything is written."""
    db = tmp_path / "poses.h5"
    assert main(["db", "import", "bundled:cmu_75_18_high_sit.bvh", "--db", str(db)]) == 0
    take = "cmu_75_18_high_sit"
    assert main(["db", "pose", "add", take, "39", "--name", "default", "--db", str(db)]) == 0
    assert main(["db", "pose", "add", take, "38", "--name", "lounging", "--support", "lounger",
                 "calves", "--db", str(db)]) == 0
    assert main(["db", "pose", "add", take, "37", "--name", "old_names", "--support", "torso",
                 "arms", "--db", str(db)]) == 0
    capsys.readouterr()
    assert main(["db", "list", "--kind", "pose", "--json", "--db", str(db)]) == 0
    supports = {r["name"]: r["supports"] for r in json.loads(capsys.readouterr().out)}
    assert supports == {
        "default": ["pelvis", "thighs"],
        "lounging": ["head", "upper_back", "lower_back", "pelvis", "thighs", "calves"],
        "old_names": ["upper_back", "lower_back", "pelvis", "upper_arms", "forearms"]}
    before = db.read_bytes()
    with pytest.raises(SystemExit):
        main(["db", "pose", "add", take, "36", "--name", "x", "--support", "tail",
              "--db", str(db)])
    assert "invalid choice: 'tail'" in capsys.readouterr().err
    assert db.read_bytes() == before


def test_the_parser_loads_no_numerical_work():
    # `sitrelax --help` stays fast: each command imports numpy, scipy, h5py and the solver when
    # it runs, not when the parser is built
    code = ("import sys\nfrom solver.cli import build_parser\nimport studio.cli\n"
            "build_parser(extra=studio.cli.register)\n"
            "heavy = ('numpy', 'scipy', 'h5py', 'asyncio', 'solver.body.model', 'posedb.library')\n"
            "print(sorted(m for m in heavy if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "[]"


def test_cli_start_bench_entry(capsys):
    from studio.cli import main as sitrelax

    assert sitrelax(["bench", "cli_start", "--repeats", "1", "--json"]) == 0
    (row,) = json.loads(capsys.readouterr().out)
    assert row["name"] == "cli_start" and 0 < row["median_s"] < 5


def test_a_broken_pipe_in_process_ends_the_command_with_status_1(capsys, monkeypatch):
    """In a process whose output has no file descriptor (captured, or in memory) the broken
    pipe still ends the command with status 1, and `--debug` shows it."""
    import argparse
    import io

    from solver.cli import run

    def broken(args):
        raise BrokenPipeError(32, "Broken pipe")

    parser = argparse.ArgumentParser()
    parser.add_argument("--debug", action="store_true")
    parser.set_defaults(func=broken)
    monkeypatch.setattr(sys, "stdout", io.StringIO())
    assert run(parser, []) == 1
    with pytest.raises(BrokenPipeError):
        run(parser, ["--debug"])
