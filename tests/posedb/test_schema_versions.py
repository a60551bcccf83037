"""Libraries of older schema versions: read as they are, their supports meaning what they meant,
and brought up to the current version by the first change (or a compaction), never before."""

import hashlib
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from posedb.library import PoseLibrary
from posedb.regions import BODY_REGIONS, SUPPORT_GROUPS, support_regions
from posedb.schema import SCHEMA_VERSION, SUPPORT_BITS, decode_supports, encode_supports
from posedb.verify import verify

from tests.conftest import recording

SCHEMA1 = Path(__file__).resolve().parents[2] / "fixtures" / "posedb" / "library_schema1.h5"
TORSO, LEGS, ARMS = (SUPPORT_GROUPS[g] for g in ("torso", "legs", "arms"))
# what each pose of the schema 1 file was given (fixtures/posedb/SOURCES.md), as regions
MEANT = {"perch": TORSO + LEGS, "arms_only": ARMS, "split_legs": ("thighs", "feet"),
         "every_bit": BODY_REGIONS}


def _digest(path):
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _in_order(regions):
    return tuple(r for r in BODY_REGIONS if r in regions)


@pytest.fixture
def old(tmp_path):
    path = tmp_path / "old.h5"
    shutil.copyfile(SCHEMA1, path)
    return path


def test_the_fixture_is_a_schema_1_file():
    with h5py.File(SCHEMA1, "r") as f:
        assert int(f.attrs["sitrelax_schema"]) == 1
        assert f["poses"]["supports"].dtype == np.uint8
        assert f["poses"]["supports"][:].tolist() == [18, 4, 96, 255]


def test_an_old_file_reads_unchanged_with_its_supports_as_regions(old):
    before = _digest(old)
    lib = PoseLibrary(old)
    assert lib.schema_version == 1 < SCHEMA_VERSION
    got = {p.name: p.supports for p in lib.poses()}
    assert got == {name: _in_order(regions) for name, regions in MEANT.items()}
    info, _, rot, _ = lib.pose_data("perch")
    assert rot.shape == (31, 4) and info.frame == 4
    assert verify(old) == []
    assert _digest(old) == before  # reading (and checking) writes nothing


def test_the_first_change_upgrades_the_file_and_keeps_every_old_bit(old):
    lib = PoseLibrary(old)
    with lib.edit() as ed:
        ed.add_pose("high_sit", 5, "chair_pose", supports="chair")
    assert lib.schema_version == SCHEMA_VERSION
    with h5py.File(old, "r") as f:
        assert int(f.attrs["sitrelax_schema"]) == SCHEMA_VERSION
        stored = f["poses"]["supports"][:]
    assert stored.dtype == np.uint16
    assert stored[:4].tolist() == [18, 4, 96, 255]  # the old masks, bit for bit
    got = {p.name: p.supports for p in lib.poses()}
    assert got["chair_pose"] == ("upper_back", "lower_back", "pelvis", "thighs")
    for name, regions in MEANT.items():
        assert got[name] == _in_order(regions)
    assert verify(old) == []


def test_an_upgrade_of_a_file_with_no_pose_table_change(old):
    """A change that leaves the pose table alone (a tag on a take) still writes the table in
    this version's layout."""
    lib = PoseLibrary(old)
    with lib.edit() as ed:
        ed.tag("high_sit", add=["kept"])
    with h5py.File(old, "r") as f:
        assert int(f.attrs["sitrelax_schema"]) == SCHEMA_VERSION
        assert f["poses"]["supports"].dtype == np.uint16
    assert {p.name: p.supports for p in PoseLibrary(old).poses()}["perch"] == TORSO + LEGS


def test_compacting_an_old_file_upgrades_it(old):
    lib = PoseLibrary(old)
    lib.compact()
    with h5py.File(old, "r") as f:
        assert int(f.attrs["sitrelax_schema"]) == SCHEMA_VERSION
        assert f["poses"]["supports"].dtype == np.uint16
    assert [p.supports for p in PoseLibrary(old).poses()] == \
        [_in_order(MEANT[n]) for n in ("perch", "arms_only", "split_legs", "every_bit")]


def test_a_current_file_stores_regions_only(tmp_path):
    lib = PoseLibrary(tmp_path / "new.h5", create=True)
    with lib.edit() as ed:
        ed.import_bvh(recording("cmu_75_18_high_sit.bvh"))
        ed.add_pose("cmu_75_18_high_sit", 39, "bed_pose", supports="bed")
        ed.add_pose("cmu_75_18_high_sit", 38, "default_pose")
    with h5py.File(lib.path, "r") as f:
        assert int(f.attrs["sitrelax_schema"]) == SCHEMA_VERSION
        masks = f["poses"]["supports"][:]
    coarse = sum(1 << SUPPORT_BITS.index(g) for g in SUPPORT_GROUPS)
    assert (masks & coarse == 0).all()
    bed = support_regions("bed")  # a use is stored as the regions it names
    assert masks[0] == sum(1 << SUPPORT_BITS.index(r) for r in bed)
    assert lib.pose("bed_pose").supports == bed
    assert lib.pose("default_pose").supports == ("pelvis", "thighs")  # a seat's


@pytest.mark.parametrize("names", [["torso"], ["arms", "hands"], "lounger", ["legs", "feet"],
                                   list(BODY_REGIONS)])
def test_encode_and_decode_round_trip_to_regions(names):
    from posedb.regions import support_regions

    assert decode_supports(encode_supports(names)) == support_regions(names)


def test_every_old_bit_decodes_to_what_it_meant():
    """Bit k of a schema 1 mask alone: a region, or a coarse part as its regions."""
    for k, name in enumerate(SUPPORT_BITS[:8]):
        assert decode_supports(1 << k) == _in_order(SUPPORT_GROUPS.get(name, (name,)))


def _placed_library(path):
    """A current library with a pose placed the standard way and one that carries a
    placement (as `sitrelax relax --save` stores it)."""
    from posedb.library import PosePlacement

    lib = PoseLibrary(path, create=True)
    with lib.edit() as ed:
        ed.import_bvh(recording("cmu_75_18_high_sit.bvh"))
        ed.add_pose("cmu_75_18_high_sit", 39, "captured")
        ed.add_pose("cmu_75_18_high_sit", 39, "relaxed",
                    placement=PosePlacement((0.01, -0.061, 0.02), -0.04))
    return lib


def test_a_pose_keeps_its_placement_through_changes_and_compaction(tmp_path):
    lib = _placed_library(tmp_path / "new.h5")
    assert lib.pose("captured").placement is None
    placed = lib.pose("relaxed").placement
    assert placed.offset == (0.01, -0.061, 0.02) and placed.heading == -0.04
    assert lib.pose("relaxed").as_dict()["placement"] == {"offset_m": [0.01, -0.061, 0.02],
                                                          "heading_rad": -0.04}
    assert lib.pose("captured").as_dict()["placement"] is None
    with lib.edit() as ed:  # rows before it dropped, rows after it added
        ed.delete_pose("captured")
        ed.add_pose("cmu_75_18_high_sit", 38, "later")
    lib.compact()
    lib = PoseLibrary(lib.path)
    assert lib.pose("relaxed").placement == placed and lib.pose("later").placement is None
    assert verify(lib.path) == []


def test_a_schema_2_file_reads_without_placements_and_gains_the_column_when_changed(tmp_path):
    path = tmp_path / "v2.h5"
    _placed_library(path)
    with h5py.File(path, "r+") as f:  # as version 2 wrote it: no placement column
        del f["poses"]["placement"]
        f.attrs["sitrelax_schema"] = 2
    before = _digest(path)
    lib = PoseLibrary(path)
    assert lib.schema_version == 2
    assert [p.placement for p in lib.poses()] == [None, None]
    assert verify(path) == [] and _digest(path) == before
    with lib.edit() as ed:
        ed.tag("cmu_75_18_high_sit", add=["kept"])  # (the pose table left alone)
    with h5py.File(path, "r") as f:
        assert int(f.attrs["sitrelax_schema"]) == SCHEMA_VERSION == 3
        assert np.isnan(f["poses"]["placement"][:]).all()
        assert f["poses"]["placement"].shape == (2, 4)
    assert verify(path) == []


@pytest.mark.parametrize("offset, heading", [((0.0, float("nan"), 0.0), 0.0),
                                             ((0.0, 0.0, 0.0), float("inf")), ((0.0, 0.0), 0.0)])
def test_a_placement_that_is_not_numbers_is_refused(offset, heading):
    from posedb.library import PosePlacement
    from posedb.schema import InvalidDataError

    with pytest.raises(InvalidDataError, match=r"Expected a placement as an offset \(x, y, z\) "
                                               r"in metres and a heading in radians, all finite"):
        PosePlacement(offset, heading)
