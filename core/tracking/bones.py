"""Bone models for tracking: CT sub-volume, bone mask, centroid and surface mesh.

A :class:`BoneModel` bundles what registration and kinematics need of one bone:

* ``volume`` — the bone's CT sub-volume in HU (:class:`core.render.CTVolume`; physical frame =
  the CT's, mm), cropped to the bone plus a margin. From a CT + label map, voxels of *other*
  labels inside the crop are set to air (-1000 HU) so neighbouring bones never enter its DRR;
  with ``isolate_mm`` every voxel farther than that from the bone (:func:`bone_hull`: the bone
  mask with its marrow filled) is set to air too, so that nothing but the bone — not the crop's
  soft tissue, nor its CT noise — gives the DRR support. The similarity's domain Ω is the DRR's
  support (:mod:`core.similarity.domain`); rendered with a transfer that keeps soft tissue above
  zero (e.g. the excess over 40 HU without a threshold), the noise of a CT's soft tissue makes Ω
  the whole projected crop, and structures there that the model lacks (soft tissue, a fibula)
  pull the optimum: on the harder foot trial (core.studies.tracking.hard_trial, 256² views,
  noise-free frames, the tibia registered from its true pose, this 2-core CPU machine) the tibia
  sat 0.61° off about its long axis with Ω the crop, 0.05° with the isolated model;
* ``mask`` — ``volume.data >= threshold`` (bool, ``[k, j, i]``);
* ``centroid`` — mean physical position (mm) of the mask voxels, the centre about which
  optimisers rotate the bone (:func:`core.geometry.transforms.pose_from_params`);
* ``vertices``/``faces`` — a closed triangle mesh of the iso-surface ``HU = threshold`` in the
  CT's physical frame (mm), for display and bone-to-bone distances.

Surface extraction: marching tetrahedra
---------------------------------------
scikit-image/VTK are not dependencies of ``core``, so the iso-surface is extracted here with
marching tetrahedra on the Freudenthal (Kuhn) subdivision of every voxel cube into six
tetrahedra that share the cube's main diagonal (Bloomenthal, *Polygonization of implicit
surfaces*, 1988; Treece, Prager & Gee, *Regularised marching tetrahedra*, 1999). Because the
subdivision is the same in every cube, neighbouring cubes agree on their shared faces and the
mesh is watertight; each tetrahedron contributes 0, 1 (one or three vertices inside) or 2 (two
inside: a quad) triangles, with vertices linearly interpolated on the crossed edges and merged
by edge so that the mesh is indexed. The field is padded with "outside", so the surface is closed
even where bone touches the crop's border. Triangles are oriented with outward normals (towards
lower HU). Marching tetrahedra makes ~2x more triangles than marching cubes, with no ambiguous
cases.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property
from itertools import permutations

import numpy as np

from ..render.volume import CTVolume

__all__ = ["BoneModel", "bone_hull", "bone_model", "marching_tetrahedra", "mesh_area", "mesh_volume"]

AIR_HU = -1000.0


def _tetrahedra() -> np.ndarray:
    """(6, 4, 3) corner offsets (dk, dj, di) of the Kuhn tetrahedra of a unit cube."""
    tets = []
    for perm in permutations(range(3)):
        p = np.zeros(3, dtype=int)
        verts = [p.copy()]
        for axis in perm:
            p[axis] = 1
            verts.append(p.copy())
        tets.append(verts)
    return np.array(tets)


_TETS = _tetrahedra()


def marching_tetrahedra(field: np.ndarray, *, level: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Closed iso-surface ``field == level`` of a 3-D array, inside = ``field >= level``.

    Parameters
    ----------
    field : (nk, nj, ni) array
        Scalar samples on a unit grid.
    level : float
        Iso-value; samples equal to it count as inside.

    Returns
    -------
    vertices : (n, 3) float64
        Positions in continuous index coordinates ``(i, j, k)`` (column, row, slice).
    faces : (m, 3) int64
        Vertex indices, counter-clockwise seen from outside (normals point to lower values).
    """
    f = np.asarray(field, dtype=np.float64)
    if f.ndim != 3 or min(f.shape) < 1:
        raise ValueError(f"field: expected a non-empty 3-D array, got shape {f.shape}")
    if not np.all(np.isfinite(f)):
        raise ValueError("field: contains NaN or infinite values")
    g = f - float(level)
    g[g == 0] = 1e-9  # ties are inside, and no vertex sits exactly on a grid point
    outside = -max(1.0, float(np.abs(g).max()))
    g = np.pad(g, 1, constant_values=outside)
    inside = g > 0
    shape = np.array(g.shape)
    # active cubes: corners of mixed sign
    c = [inside[dk:dk + shape[0] - 1, dj:dj + shape[1] - 1, di:di + shape[2] - 1]
         for dk in (0, 1) for dj in (0, 1) for di in (0, 1)]
    any_in = np.logical_or.reduce(c)
    all_in = np.logical_and.reduce(c)
    base = np.argwhere(any_in & ~all_in)  # (n_cubes, 3) (k, j, i)
    if len(base) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    corners = base[:, None, None, :] + _TETS[None]  # (n, 6, 4, 3)
    corners = corners.reshape(-1, 4, 3)
    lin = np.ravel_multi_index(tuple(np.moveaxis(corners, -1, 0)), tuple(shape))  # (T, 4)
    val = g.reshape(-1)[lin]
    ins = val > 0
    n_in = ins.sum(axis=1)
    order = np.argsort(~ins, axis=1, kind="stable")  # inside vertices first
    sl = np.take_along_axis(lin, order, axis=1)
    tri_edges, tri_ref = [], []
    # one vertex inside: edges from it to the three others
    for n_inside in (1, 3):
        idx = np.flatnonzero(n_in == n_inside)
        if idx.size == 0:
            continue
        s = sl[idx]
        if n_inside == 1:
            lone, others = s[:, 0], s[:, 1:]
        else:
            lone, others = s[:, 3], s[:, :3]
        e = np.stack([np.stack([lone, others[:, m]], axis=-1) for m in range(3)], axis=1)  # (n,3,2)
        tri_edges.append(e)
        tri_ref.append(idx)
    idx = np.flatnonzero(n_in == 2)
    if idx.size:
        s = sl[idx]
        a, b, c2, d = s[:, 0], s[:, 1], s[:, 2], s[:, 3]  # a, b inside; c2, d outside
        ac, ad, bd, bc = (np.stack(p, axis=-1) for p in ((a, c2), (a, d), (b, d), (b, c2)))
        tri_edges += [np.stack([ac, ad, bd], axis=1), np.stack([ac, bd, bc], axis=1)]
        tri_ref += [idx, idx]
    E = np.concatenate(tri_edges)  # (m, 3, 2): for each triangle corner, edge (inside pt, outside pt)
    ref = np.concatenate(tri_ref)
    # orient each edge as (inside, outside) for interpolation
    gv = g.reshape(-1)
    p_in = np.where(gv[E[..., 0]] > 0, E[..., 0], E[..., 1])
    p_out = np.where(gv[E[..., 0]] > 0, E[..., 1], E[..., 0])
    keys = p_in.astype(np.int64) * int(np.prod(shape)) + p_out
    uniq, inv = np.unique(keys.reshape(-1), return_inverse=True)
    ui, uo = uniq // int(np.prod(shape)), uniq % int(np.prod(shape))
    fi, fo = gv[ui], gv[uo]
    t = fi / (fi - fo)
    xi = np.array(np.unravel_index(ui, tuple(shape))).T.astype(float)
    xo = np.array(np.unravel_index(uo, tuple(shape))).T.astype(float)
    verts_kji = xi + t[:, None] * (xo - xi) - 1.0  # undo the padding
    faces = inv.reshape(-1, 3)
    # orientation: the normal must point from the tetrahedron's inside vertices to its outside ones
    vin = np.where(ins[ref][..., None], corners[ref], 0).sum(axis=1) / n_in[ref][:, None]
    vout = np.where(~ins[ref][..., None], corners[ref], 0).sum(axis=1) / (4 - n_in[ref])[:, None]
    P = verts_kji[faces]
    nrm = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    flip = np.einsum("ij,ij->i", nrm, (vout - vin).astype(float)) < 0
    faces[flip] = faces[flip][:, ::-1]
    good = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    # (k, j, i) -> (i, j, k) swaps two axes, a reflection: reverse the winding with it
    return verts_kji[:, ::-1].copy(), faces[good][:, ::-1].astype(np.int64)


def mesh_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Enclosed volume of a closed, outward-oriented mesh (divergence theorem), units³."""
    P = np.asarray(vertices, dtype=float)[np.asarray(faces)]
    return float(np.einsum("ij,ij->i", P[:, 0], np.cross(P[:, 1], P[:, 2])).sum() / 6.0)


def mesh_area(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Surface area of a triangle mesh, units²."""
    P = np.asarray(vertices, dtype=float)[np.asarray(faces)]
    return float(0.5 * np.linalg.norm(np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]), axis=1).sum())


@dataclass(frozen=True, eq=False)
class BoneModel:
    """One bone ready for tracking (see the module docs).

    Attributes
    ----------
    name : str
    volume : CTVolume
        Cropped CT in HU (other labels set to air).
    threshold : float
        Bone threshold in HU.
    mask : (nk, nj, ni) bool array
        ``volume.data >= threshold``.
    centroid : (3,) array
        Mask centroid in the CT's physical frame, mm.
    vertices : (n, 3) array
        Surface mesh vertices in the CT's physical frame, mm (empty when ``mesh=False``).
    faces : (m, 3) int array
        Outward-oriented triangles.
    """

    name: str
    volume: CTVolume
    threshold: float
    mask: np.ndarray
    centroid: np.ndarray
    vertices: np.ndarray
    faces: np.ndarray

    @property
    def n_voxels(self) -> int:
        return int(self.mask.sum())

    @cached_property
    def outline(self) -> np.ndarray:
        """``(n, 3)`` points (CT physical frame, mm) whose convex hull holds every voxel the DRR
        of the bone can touch: the convex-hull vertices of the mask's voxel centres, each moved
        by ±1 voxel along every axis (trilinear support). Projected, they bound the bone's
        image more tightly than the crop's box (search ROIs, :func:`core.tracking.cost.search_roi`)."""
        from scipy.ndimage import binary_erosion
        from scipy.spatial import ConvexHull, QhullError

        shell = self.mask & ~binary_erosion(self.mask)
        k, j, i = np.nonzero(shell)
        P = np.column_stack([i, j, k]).astype(float)
        try:
            P = P[ConvexHull(P).vertices]
        except (QhullError, ValueError):  # flat or tiny masks: keep every shell voxel
            pass
        corners = np.array([[a, b, c] for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)], float)
        out = self.volume.index_to_physical((P[:, None, :] + corners[None]).reshape(-1, 3))
        out.setflags(write=False)
        return out

    def surface_points(self, pose: np.ndarray) -> np.ndarray:
        """Mesh vertices mapped by ``pose`` (4x4 ``T_lab_from_bone``) into the lab, mm."""
        T = np.asarray(pose, dtype=float)
        return self.vertices @ T[:3, :3].T + T[:3, 3]


def bone_hull(mask: np.ndarray, spacing, rim_mm: float = 1.0) -> np.ndarray:
    """The bone's region of a bone ``mask`` ``(nk, nj, ni)``: the mask with its cavities filled
    (marrow, trabecular spaces — in 3-D, and slice by slice along each axis for a canal open at
    a cut end of the crop) and grown by ``rim_mm`` (voxel ``spacing`` (i, j, k) mm; at least one
    voxel when ``rim_mm`` > 0: the partial-volume voxels of the bone's edge)."""
    from scipy import ndimage

    m = np.asarray(mask, dtype=bool)
    if not (np.isfinite(rim_mm) and rim_mm >= 0):
        raise ValueError(f"isolate_mm: expected a distance >= 0 mm, got {rim_mm!r}")
    hull = ndimage.binary_fill_holes(m)
    for ax in range(3):
        sl = np.moveaxis(m, ax, 0)
        hull |= np.moveaxis(np.stack([ndimage.binary_fill_holes(s) for s in sl]), 0, ax)
    if rim_mm > 0:
        sp = np.asarray(spacing, dtype=float)[::-1]  # (k, j, i)
        r = np.maximum(np.ceil(rim_mm / sp - 1e-9).astype(int), 1)
        k, j, i = np.ogrid[-r[0]:r[0] + 1, -r[1]:r[1] + 1, -r[2]:r[2] + 1]
        ball = (k * sp[0]) ** 2 + (j * sp[1]) ** 2 + (i * sp[2]) ** 2 <= max(rim_mm, sp.max()) ** 2 + 1e-9
        hull = ndimage.binary_dilation(hull, structure=ball)
    return hull


def bone_model(
    volume: CTVolume,
    *,
    name: str | None = None,
    threshold: float = 200.0,
    labels=None,
    label: int | None = None,
    margin_mm: float = 5.0,
    mesh: bool = True,
    mesh_step: int = 1,
    isolate_mm: float | None = None,
) -> BoneModel:
    """Build a :class:`BoneModel` from a CT volume (HU), optionally with a label map.

    Parameters
    ----------
    volume : CTVolume
        CT in HU: a bone sub-volume, or a whole CT with ``labels``.
    name : str, optional
        Default ``volume.name``.
    threshold : float
        Bone threshold (HU) for the mask, centroid and surface.
    labels : array or CTVolume, optional
        Integer label map on ``volume``'s grid; with ``label``, the volume is cropped to that
        label's bounding box + ``margin_mm`` and other labels are set to air.
    label : int, optional
        The bone's label value (required with ``labels``).
    margin_mm : float
        Crop margin around the bone, mm (also used without labels: the volume is cropped to the
        thresholded bone + margin).
    mesh : bool
        Extract the surface mesh (the slowest step: skip it when only registering).
    mesh_step : int
        Voxel stride of the mesh (2 → block-averaged to half resolution first; coarser mesh).
    isolate_mm : float, optional
        Set every voxel farther than this (mm) from the bone to air (:func:`bone_hull`): the
        crop's soft tissue, CT noise and stray neighbours then never enter the bone's DRR, whatever
        the transfer. Default None keeps the crop as it is.

    Raises
    ------
    ValueError
        When no voxel of the bone reaches ``threshold`` (the message names the bone and the
        volume's range), the label is absent, or the arguments are inconsistent.
    """
    if not isinstance(volume, CTVolume):
        raise ValueError("volume: expected a core.render.CTVolume")
    if volume.units != "HU":
        raise ValueError(f"volume: expected a CT in HU, got units {volume.units!r}")
    nm = name if name is not None else (volume.name or "bone")
    if margin_mm < 0 or not np.isfinite(margin_mm):
        raise ValueError(f"margin_mm: expected a finite margin >= 0 mm, got {margin_mm!r}")
    if int(mesh_step) != mesh_step or mesh_step < 1:
        raise ValueError(f"mesh_step: expected an integer >= 1, got {mesh_step!r}")
    vol = volume
    if labels is not None or label is not None:
        if labels is None or label is None:
            raise ValueError("labels, label: give both (a label map and the bone's label value) or neither")
        lab = labels.data if isinstance(labels, CTVolume) else np.asarray(labels)
        if lab.shape != volume.data.shape:
            raise ValueError(f"labels: expected the CT's shape {volume.data.shape}, got {lab.shape}")
        sel = lab == label
        if not sel.any():
            raise ValueError(f"label: no voxel of the label map has the value {label!r} (bone {nm!r})")
        data = np.where(sel | (lab == 0), volume.data, np.asarray(AIR_HU, dtype=volume.data.dtype))
        vol = replace(volume, data=data)
        vox = np.ceil(margin_mm / vol.spacing).astype(int)
        idx = np.nonzero(sel)
        lo = [max(int(a.min()) - int(m), 0) for a, m in zip(idx, vox[::-1], strict=True)]
        hi = [min(int(a.max()) + int(m) + 1, n)
              for a, m, n in zip(idx, vox[::-1], vol.data.shape, strict=True)]
        vol = vol.crop(slice(lo[2], hi[2]), slice(lo[1], hi[1]), slice(lo[0], hi[0]))
    mask = vol.data >= threshold
    if not mask.any():
        raise ValueError(
            f"threshold: no voxel of bone {nm!r} is >= {threshold} HU "
            f"(its CT ranges {vol.data.min()}..{vol.data.max()} HU)"
        )
    if labels is None:
        vox = int(np.ceil(margin_mm / vol.spacing.min()))
        vol = vol.crop_to_mask(mask, margin=vox)
        mask = vol.data >= threshold
    if isolate_mm is not None:
        hull = bone_hull(mask, vol.spacing, isolate_mm)
        vol = replace(vol, data=np.where(hull, vol.data, np.asarray(AIR_HU, dtype=vol.data.dtype)))
    k, j, i = np.nonzero(mask)
    centroid = vol.index_to_physical(np.column_stack([i, j, k]).mean(axis=0))
    verts, faces = np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    if mesh:
        data = vol.data.astype(np.float32)
        s = int(mesh_step)
        if s > 1:
            nk, nj, ni = (n // s * s for n in data.shape)
            data = data[:nk, :nj, :ni].reshape(nk // s, s, nj // s, s, ni // s, s).mean(axis=(1, 3, 5))
        v_ijk, faces = marching_tetrahedra(data, level=threshold)
        if s > 1:
            v_ijk = v_ijk * s + (s - 1) / 2.0
        verts = vol.index_to_physical(v_ijk) if len(v_ijk) else v_ijk
    vol = replace(vol, name=nm)
    for a in (mask, centroid, verts, faces):
        a.setflags(write=False)
    return BoneModel(nm, vol, float(threshold), mask, centroid, verts, faces)
