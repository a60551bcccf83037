"""Review of `sitrelax relax` and `sitrelax pose show`: a surface the people cannot be relaxed
onto (its faces reversed) is refused with one line and exit status 2, nothing written; `--save`
stores nothing when the results cannot be written; a joint map's error names the map."""

import shutil
from pathlib import Path

import pytest

from solver.cli import main
from solver.scene.run import run_fit

SEATED = Path(__file__).resolve().parents[3] / "fixtures" / "scenarios" / "single_seated.toml"


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """A fit of the seated example (surface.obj only, no pictures)."""
    out = tmp_path_factory.mktemp("fit")
    run_fit(SEATED, out, formats=("obj",), pictures=False)
    return out


def _flipped_copy(fitted: Path, to: Path) -> Path:
    """The fit's folder with every face of surface.obj reversed (a surface modelled elsewhere
    with its normals pointing down, away from the sitter)."""
    shutil.copytree(fitted, to)
    lines = (to / "surface.obj").read_text().splitlines()
    flipped = ["f " + " ".join(reversed(line.split()[1:])) if line.startswith("f ") else line
               for line in lines]
    (to / "surface.obj").write_text("\n".join(flipped) + "\n")
    return to


def test_relax_refuses_a_surface_facing_away_from_the_people(fitted, tmp_path, capsys):
    surface = _flipped_copy(fitted, tmp_path / "flipped")
    out = tmp_path / "relaxed"
    code = main(["relax", str(SEATED), "--surface", str(surface), "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert err[-1].startswith("sitrelax: error: Expected a surface whose faces point towards "
                              "the people: ")
    assert "flip it" in err[-1] and "Traceback" not in "\n".join(err)
    assert not out.exists()


def test_relax_onto_its_own_fit_is_not_refused(fitted, tmp_path, capsys):
    out = tmp_path / "relaxed"
    assert main(["relax", str(SEATED), "--surface", str(fitted), "--out", str(out)]) == 0
    assert (out / "report.json").is_file()


def test_relax_save_stores_nothing_when_the_results_cannot_be_written(fitted, tmp_path,
                                                                      monkeypatch, capsys):
    """`--save` stores the relaxed pose only once the results are written: a relaxation whose
    picture cannot be written (a full disk) leaves the library as it was, so that running it
    again does not store a second copy (`<origin>-relaxed-2`)."""
    import solver.scene.run as run
    from posedb import PoseLibrary
    from tests.conftest import high_sit_library

    db = high_sit_library(tmp_path / "poses.h5", [(39, "perch", ("sit",))])
    scenario = tmp_path / "scene.toml"
    scenario.write_text(SEATED.read_text().replace(
        'pose = "bvh:bundled:cmu_75_18_high_sit.bvh#frame=39"', 'pose = "db:perch"'))

    def full_disk(path, *args, **kwargs):
        raise OSError(28, "No space left on device", str(path))

    monkeypatch.setattr(run, "render_panels", full_disk)
    out = tmp_path / "relaxed"
    code = main(["relax", str(scenario), "--surface", str(fitted), "--db", str(db), "--save",
                 "--out", str(out)])
    assert code == 2
    assert "No space left on device" in capsys.readouterr().err
    assert not out.exists()
    assert [p.name for p in PoseLibrary(db).poses()] == ["perch"]
    assert [t.name for t in PoseLibrary(db).takes()] == ["high_sit"]


def test_pose_show_blames_the_joint_map_for_its_unknown_role(tmp_path, capsys):
    """A joint map naming a role that does not exist: the error names the map as at fault,
    not the BVH file it was given for."""
    (tmp_path / "map.toml").write_text('pelvis = "Hips"\n')
    out = tmp_path / "posed.obj"
    code = main(["pose", "show", "bundled:cmu_75_18_high_sit.bvh#frame=39", "--joint-map",
                 str(tmp_path / "map.toml"), "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert err[0].startswith("sitrelax: error: The joint map for ")
    assert "cmu_75_18_high_sit.bvh: unknown role 'pelvis'" in err[0]
    assert not out.exists()
