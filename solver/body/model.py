"""Bodies of any shape, from the MakeHuman CC0 base mesh, macro targets and CMU-MB rig.

A body is made from shape parameters in [0, 1] that follow MakeHuman's macro modifiers: gender
(0 female .. 1 male), age (0 baby, 0.1875 child, 0.5 young adult, 1 old), muscle, weight, height
and proportions (0.5 each is average), and race weights. Each macro target moves the base mesh by
its offsets times the product of the weights its states get from the parameters (for example
`universal-male-young-maxmuscle-averageweight` by male x young x maxmuscle x averageweight).

The body is in metres, Y up, facing +Z, standing with its feet on y = 0 and its pelvis over the
origin. Its rig's joints sit at the centres of the joint cubes of the shaped mesh, so they follow
the shape. Mass is the enclosed volume times `BODY_DENSITY`.

The packed assets are unpacked once and kept, one array a file, in a cache folder
(`asset_cache_dir`: `SITRELAX_CACHE`, else `~/.cache/sitrelax`; `SITRELAX_CACHE=off` keeps
none), from which later runs map them.
"""

from __future__ import annotations

import hashlib
import io
import lzma
import os
import shutil
import tempfile
from dataclasses import dataclass, field, fields
from functools import cached_property, lru_cache
from importlib import resources
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from capture.skeleton import joint_levels
from posedb.regions import BODY_REGIONS, SUPPORT_GROUPS, support_regions

from solver.mesh import area_weighted_normals, enclosed_volume, quad_triangles
from .sliders import SHAPE_KEYS  # noqa: F401 (the sliders)

BODY_DENSITY = 1010.0  # kg/m^3: whole-body density with air in the lungs
DM = 0.1  # metres per asset unit (decimetres)

# The body regions (`posedb.regions.BODY_REGIONS`: what supports name and the mat's figures are
# given for), each made of the CMU-MB bones that move it. The trunk's regions span front and
# back and are named for the side a seat or backrest touches; the shoulders' collar bones are
# the upper back's, and "pelvis" includes the buttocks, which the hip bones carry.
REGION_BONES = {
    "head": ("Head", "Neck", "Neck1"),
    "upper_back": ("Spine", "Spine1", "LeftShoulder", "RightShoulder"),
    "lower_back": ("LowerBack",),
    "pelvis": ("Hips", "LHipJoint", "RHipJoint"),
    "thighs": ("LeftUpLeg", "RightUpLeg"),
    "calves": ("LeftLeg", "RightLeg"),
    "feet": ("LeftFoot", "LeftToeBase", "RightFoot", "RightToeBase"),
    "upper_arms": ("LeftArm", "RightArm"),
    "forearms": ("LeftForeArm", "RightForeArm"),
    "hands": ("LeftHand", "LeftFingerBase", "LeftHandFinger1", "LThumb", "RightHand",
              "RightFingerBase", "RightHandFinger1", "RThumb"),
}
# The coarse parts the regions refine: a region's part is the group holding it
# (`posedb.regions.SUPPORT_GROUPS`: torso, arms, legs), or the region itself.
BODY_PARTS = ("head", "torso", "arms", "hands", "legs", "feet")
REGION_PART = {r: next((g for g, rs in SUPPORT_GROUPS.items() if r in rs), r)
               for r in BODY_REGIONS}
if set(REGION_BONES) != set(BODY_REGIONS) or set(REGION_PART.values()) != set(BODY_PARTS):
    raise ImportError("solver.body.model: REGION_BONES, BODY_REGIONS and BODY_PARTS disagree")


# per trunk region, the most a supported skin vertex's rest normal may face forward (+Z)
TRUNK_FACING = {"upper_back": 0.0, "lower_back": 0.0, "pelvis": 0.5}
# metres along the thigh bone, before the knee, that a support of the thighs without the
# calves leaves free: a seat's front edge under the back of the knee (the popliteal fossa)
# presses its nerves and vessels and, on a seat whose calves hang, the top of the calves;
# seating guidance leaves a hand's breadth between them. 11 cm, where the templates' seats end
# (`solver.scene.furnish.KNEE_PIT`); at 8 cm the gallery's bench and lounger put their peaks on
# the calves, at 11 cm on the thighs and the head
POPLITEAL_CLEARANCE = 0.11
# metres from the calves' skin, in the pose, within which a support of the thighs without the
# calves leaves the thighs' skin free as well: where the knee bends further than a right angle
# the back of the thigh comes down beside the calf, and a seat's rim kept clear of the calves
# (the fit's rim rows keep 3 cm, `solver.surface.fit.RIM_CLEARANCE`, and more where the calf
# lies deeper in the foam) cannot reach the thigh's skin there. 4 cm: that clearance and a
# centimetre; at 3 cm a deep-kneed sitter of six_overlapping still missed 0.05 of its support
KNEE_CREASE = 0.04


class BodyShapeError(ValueError):
    """Shape parameters outside what the body model accepts."""




@dataclass(frozen=True)
class BodyShape:
    """Shape parameters, each in [0, 1]; the defaults give MakeHuman's average adult."""

    gender: float = 0.5
    age: float = 0.5
    muscle: float = 0.5
    weight: float = 0.5
    height: float = 0.5
    proportions: float = 0.5
    african: float = 1 / 3
    asian: float = 1 / 3
    caucasian: float = 1 / 3

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            try:
                value = float(value)
            except (TypeError, ValueError):
                raise BodyShapeError(f"Expected a number for body {f.name}, got {value!r}") from None
            if not (0.0 <= value <= 1.0):
                raise BodyShapeError(f"Expected body {f.name} in [0, 1], got {value} (a shape "
                                     "slider, not a measure: 0.5 is the average adult)")
            object.__setattr__(self, f.name, value)
        if self.african + self.asian + self.caucasian <= 0:
            raise BodyShapeError("Expected race weights that are not all zero")

    @classmethod
    def from_mapping(cls, values: dict) -> "BodyShape":
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise BodyShapeError(f"Expected body parameters from {sorted(known)}, got {unknown}")
        return cls(**values)

    def as_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @property
    def age_years(self) -> float:
        """MakeHuman's age scale: 1 year at 0, 11 at 0.1875, 25 at 0.5, 90 at 1."""
        a = self.age
        if a < 0.1875:
            return 1 + a / 0.1875 * 10
        if a < 0.5:
            return 11 + (a - 0.1875) / 0.3125 * 14
        return 25 + (a - 0.5) / 0.5 * 65

    def state_weights(self) -> dict[str, float]:
        """Weight of every named macro state (female, young, maxweight, asian, ...)."""
        g, a, m, w, h, p = self.gender, self.age, self.muscle, self.weight, self.height, \
            self.proportions
        s = {"female": 1 - g, "male": g}
        if a < 0.5:
            baby = max(0.0, 1 - a / 0.1875)
            young = max(0.0, (a - 0.1875) / 0.3125)
            s.update(baby=baby, child=max(0.0, min(1.0, a / 0.1875) - young), young=young, old=0)
        else:
            s.update(baby=0, child=0, old=2 * a - 1, young=2 - 2 * a)
        for name, v in (("muscle", m), ("weight", w)):
            if v < 0.5:
                s.update({f"min{name}": 1 - 2 * v, f"average{name}": 2 * v, f"max{name}": 0})
            else:
                s.update({f"min{name}": 0, f"average{name}": 2 - 2 * v, f"max{name}": 2 * v - 1})
        s.update(minheight=max(0.0, 1 - 2 * h), maxheight=max(0.0, 2 * h - 1))
        s.update(uncommonproportions=max(0.0, 1 - 2 * p), idealproportions=max(0.0, 2 * p - 1))
        total = self.african + self.asian + self.caucasian
        s.update(african=self.african / total, asian=self.asian / total,
                 caucasian=self.caucasian / total)
        return s


@lru_cache(maxsize=1)
def _assets() -> dict:
    blob = (resources.files("solver") / "data" / "makehuman_body.npz.xz").read_bytes()
    assets = _cached_assets(blob)
    names = [str(n) for n in assets["target_names"]]
    # each target's states: "height/female-young-averagemuscle-minweight-maxheight" ->
    # female, young, averagemuscle, minweight, maxheight ("universal" is no state)
    assets["target_states"] = [
        [s for s in n.rsplit("/", 1)[-1].split("-") if s != "universal"] for n in names
    ]
    return assets


CACHE_ENV = "SITRELAX_CACHE"  # where the unpacked assets are kept ("off": nowhere)


def asset_cache_dir() -> Path | None:
    """The folder that keeps the body assets unpacked: `SITRELAX_CACHE`, else
    `$XDG_CACHE_HOME/sitrelax` (`~/.cache/sitrelax`); None when `SITRELAX_CACHE` is "off"."""
    value = os.environ.get(CACHE_ENV, "").strip()
    if value.lower() == "off":
        return None
    if value:
        return Path(value)
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "sitrelax"


def _cached_assets(blob: bytes) -> dict:
    """The arrays of the packed assets (`blob`, an xz-compressed .npz). Unpacking takes about
    half a second, so the arrays are also kept unpacked, one .npy each, in a folder of
    `asset_cache_dir` named by the package's hash; later runs map them from there (only the
    pages a body's active targets use are read). A cache that cannot be written or read is
    passed by: the arrays are unpacked in memory as before."""
    root = asset_cache_dir()
    folder = None if root is None else \
        root / f"body-{hashlib.sha256(blob).hexdigest()[:16]}"
    if folder is not None:
        try:
            names = (folder / "names.txt").read_text().split()
            return {k: np.load(folder / f"{k}.npy", mmap_mode="r") for k in names}
        except (OSError, ValueError):
            pass
    with np.load(io.BytesIO(lzma.decompress(blob))) as data:
        assets = {k: data[k] for k in data.files}
    if folder is not None:
        _write_cache(folder, assets)
    return assets


def _write_cache(folder: Path, assets: dict) -> None:
    """The arrays as .npy files in a temporary folder renamed into place whole (a reader sees
    all of them or none); any failure leaves no cache."""
    tmp = None
    try:
        folder.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", dir=folder.parent))
        for key, value in assets.items():
            np.save(tmp / f"{key}.npy", value, allow_pickle=False)
        (tmp / "names.txt").write_text("\n".join(assets))
        os.replace(tmp, folder)
    except (OSError, ValueError):
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)  # another process's cache won the race


def _mean_rows(points: np.ndarray, index: np.ndarray, ptr: np.ndarray) -> np.ndarray:
    sums = np.add.reduceat(points[index], ptr[:-1], axis=0)
    return sums / np.diff(ptr)[:, None]


@dataclass(frozen=True, eq=False)
class Body:
    """A shaped body in its rest pose, with its rig.

    vertices : (V, 3) float metres, the skin (no helper geometry).
    faces : (F, 4) int quads; `triangles` (2F, 3) splits each along its first diagonal.
    joint_names, parents : the rig (CMU-MB: names match CMU BVH files), parents first.
    joints : (J, 3) rest positions of the joints (bone heads), metres.
    tails : (J, 3) rest positions of the bone tails (where a leaf bone ends).
    weights : (V, J) scipy.sparse CSR skinning weights, non-negative, rows summing to 1.
    parts : (V,) int index into BODY_PARTS: the part whose bones weigh most on the vertex.
    """

    shape: BodyShape
    vertices: np.ndarray
    faces: np.ndarray
    joint_names: tuple[str, ...]
    parents: np.ndarray
    joints: np.ndarray
    tails: np.ndarray
    weights: sp.csr_matrix
    parts: np.ndarray = field(repr=False)

    @cached_property
    def triangles(self) -> np.ndarray:
        return quad_triangles(self.faces)

    @cached_property
    def normals(self) -> np.ndarray:
        """(V, 3) rest-pose unit normals, area-weighted over the incident triangles."""
        return area_weighted_normals(self.vertices, self.triangles)

    @cached_property
    def height_m(self) -> float:
        return float(np.ptp(self.vertices[:, 1]))

    @cached_property
    def volume_m3(self) -> float:
        """Enclosed volume (divergence theorem over the closed skin)."""
        return enclosed_volume(self.vertices, self.triangles)

    @cached_property
    def mass_kg(self) -> float:
        return self.volume_m3 * BODY_DENSITY

    @cached_property
    def weight_levers(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The skinning weights' entries as (vertex, joint, weight) arrays and each entry's rest
        distance (m) from the vertex to the joint."""
        w = self.weights.tocoo()
        lever = np.linalg.norm(self.vertices[w.row] - self.joints[w.col], axis=1)
        return w.row, w.col, w.data, lever

    @cached_property
    def levels(self) -> tuple[np.ndarray, ...]:
        """The rig's joints grouped by depth, for forward kinematics level by level."""
        return joint_levels(self.parents)

    def joint_index(self, name: str) -> int:
        try:
            return self.joint_names.index(name)
        except ValueError:
            raise KeyError(f"No joint {name!r}; joints are {list(self.joint_names)}") from None

    @cached_property
    def regions(self) -> np.ndarray:
        """(V,) int8 index into BODY_REGIONS: of the regions of the vertex's part, the one whose
        bones weigh most on it (a tie goes to the region listed first).

        Regions refine the parts: every vertex of a region belongs to its REGION_PART, so the
        regions of a coarse part (torso, arms, legs) cover exactly the vertices of that part."""
        rows = [self.joint_index(b) for r in BODY_REGIONS for b in REGION_BONES[r]]
        cols = [k for k, r in enumerate(BODY_REGIONS) for _ in REGION_BONES[r]]
        incidence = sp.csr_matrix((np.ones(len(rows)), (rows, cols)),
                                  shape=(len(self.joint_names), len(BODY_REGIONS)))
        per_region = (self.weights @ incidence).toarray()
        region_part = np.array([BODY_PARTS.index(REGION_PART[r]) for r in BODY_REGIONS])
        per_region[region_part[None, :] != self.parts[:, None]] = -1.0
        return per_region.argmax(axis=1).astype(np.int8)

    def part_mask(self, names, posed: np.ndarray | None = None) -> np.ndarray:
        """(V,) bool: the vertices of the body regions a support names.

        Parameters
        ----------
        names : str or iterable of str
            Regions, coarse parts (torso, arms, legs) or uses (seat, chair, ...), as
            `posedb.regions.support_regions` reads them.
        posed : (V, 3) float, optional
            The skin in the pose it is supported in: a support of the thighs without the
            calves then also leaves free the thighs' skin within KNEE_CREASE of the calves'.

        Returns
        -------
        (V,) bool
            The named regions' vertices; of the trunk's regions only the skin that does not
            face forward in the rest pose (`TRUNK_FACING`), unless the torso or a bed is named.

        Raises
        ------
        SupportNameError
            If a name is no region, part or use.
        """
        regions = support_regions(names)
        mask = np.isin(self.regions, [BODY_REGIONS.index(r) for r in regions])
        # the trunk's regions span front and back; named as regions or by a seat's, chair's or
        # lounger's use, a support carries their back (a backrest the back, a seat the
        # buttocks): skin that faces forward in the rest pose (the body faces +Z) is no part of
        # what they ask for, the chest and belly under the upper and lower back, the groin and
        # lower belly in front of the pelvis. The whole torso (the coarse part) and a bed (which
        # may carry a body lying on its front) keep the front.
        raw = {str(n).strip().lower() for n in ([names] if isinstance(names, str) else names)}
        if raw & {"torso", "bed"}:
            return mask
        facing = self.normals[:, 2]
        for region, most in TRUNK_FACING.items():
            if region in regions:
                mask[(self.regions == BODY_REGIONS.index(region)) & (facing > most)] = False
        if "thighs" in regions and "calves" not in regions:
            mask[self.popliteal] = False
            if posed is not None:
                mask[self.knee_crease(posed)] = False
        return mask

    def knee_crease(self, posed: np.ndarray) -> np.ndarray:
        """(V,) bool: the thighs' skin within KNEE_CREASE of the calves' skin, on the skin
        `posed` (V, 3) in metres."""
        from scipy.spatial import cKDTree

        posed = np.asarray(posed, dtype=np.float64)
        thighs = np.flatnonzero(self.regions == BODY_REGIONS.index("thighs"))
        calves = posed[self.regions == BODY_REGIONS.index("calves")]
        near = np.zeros(len(posed), dtype=bool)
        if len(thighs) and len(calves):
            dist, _ = cKDTree(calves).query(posed[thighs], distance_upper_bound=KNEE_CREASE)
            near[thighs[np.isfinite(dist)]] = True
        return near

    @cached_property
    def popliteal(self) -> np.ndarray:
        """(V,) bool: the thighs' skin within POPLITEAL_CLEARANCE of the knee along the thigh
        bone (rest pose), all round the knee's end of each thigh."""
        thighs = np.flatnonzero(self.regions == BODY_REGIONS.index("thighs"))
        p = self.vertices[thighs]
        along, off = [], []
        for side in ("Left", "Right"):
            hip = self.joints[self.joint_index(f"{side}UpLeg")]
            axis = self.joints[self.joint_index(f"{side}Leg")] - hip  # hip to knee
            length = float(np.linalg.norm(axis))
            t = (p - hip) @ (axis / length)
            along.append(t - length)  # metres past the knee (negative before it)
            off.append(np.linalg.norm(p - hip - np.outer(t / length, axis), axis=1))
        side = np.argmin(off, axis=0)  # each vertex's own thigh: the nearer bone
        past_knee = np.choose(side, along)
        free = np.zeros(len(self.vertices), dtype=bool)
        free[thighs[past_knee > -POPLITEAL_CLEARANCE]] = True
        return free

    def summary(self) -> dict:
        return {"shape": self.shape.as_dict(), "age_years": self.shape.age_years,
                "height_m": self.height_m, "mass_kg": self.mass_kg,
                "volume_m3": self.volume_m3, "vertices": int(len(self.vertices)),
                "faces": int(len(self.faces)), "joints": int(len(self.joint_names))}


@lru_cache(maxsize=32)
def make_body(shape: BodyShape = BodyShape()) -> Body:
    """The body of a shape (cached: bodies are immutable).

    The MakeHuman base mesh morphed by the shape's targets, standing on y = 0 with the pelvis
    over the origin, facing +Z.

    Parameters
    ----------
    shape : BodyShape, optional
        Shape parameters, each in [0, 1]; the default is MakeHuman's average adult.

    Returns
    -------
    Body
        The rest-pose body: skin vertices (V, 3) in metres, quads (F, 4), the rig's joints and
        tails (J, 3) in metres with their parents, and skinning weights (V, J); its mass
        (`Body.mass_kg`, kg) follows from the enclosed volume.
    """
    assets = _assets()
    weights = shape.state_weights()
    factors = np.array([np.prod([weights[s] for s in states])
                        for states in assets["target_states"]])
    active = np.flatnonzero(factors)
    points = assets["base_dm"].astype(np.float64)
    if active.size:
        deltas = assets["target_deltas"][active].astype(np.float64)
        points = points + np.tensordot(factors[active], deltas, axes=1) * assets["delta_unit_dm"]
    points *= DM
    n_skin = int(assets["skin_vertices"])
    joints = _mean_rows(points, assets["head_index"], assets["head_ptr"])
    tails = _mean_rows(points, assets["tail_index"], assets["tail_ptr"])
    skin = points[:n_skin]
    # stand on the floor with the pelvis over the origin
    offset = np.array([joints[0, 0], skin[:, 1].min(), joints[0, 2]])
    skin, joints, tails = skin - offset, joints - offset, tails - offset
    names = tuple(str(n) for n in assets["bone_names"])
    w = sp.csr_matrix(
        (assets["weight_values"].astype(np.float64),
         (assets["weight_rows"], assets["weight_cols"].astype(np.int64))),
        shape=(n_skin, len(names)),
    )
    bone_part = {b: REGION_PART[r] for r, bones in REGION_BONES.items() for b in bones}
    part_of_bone = np.array([BODY_PARTS.index(bone_part[n]) for n in names])
    per_part = (w @ sp.csr_matrix((np.ones(len(names)), (np.arange(len(names)), part_of_bone)),
                                  shape=(len(names), len(BODY_PARTS)))).toarray()
    for arr in (skin, joints, tails):
        arr.setflags(write=False)
    return Body(shape, skin, assets["faces"].astype(np.int64), names,
                assets["bone_parents"].astype(np.int64), joints, tails, w,
                per_part.argmax(axis=1).astype(np.int8))
