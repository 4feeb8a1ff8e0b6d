"""A complete synthetic biplane trial: rig, bones in HU, soft tissue, beads, motion, image chain.

Rendering model of one frame and view
-------------------------------------
``∫μ dl = Σ_bones DRR(bone, excess transfer) + Σ_tissue DRR(tissue) + floor plate + beads``

* Bone volumes carry soft tissue around the bone (40 HU); the soft-tissue envelope carries it
  too. To count tissue once, bones are rendered with the *excess* transfer
  ``μ(HU) - μ(HU_soft)`` (clipped at 0; :func:`excess_transfer`), the envelope with the plain
  :class:`~core.render.HUTransfer` at the same ``mu_water``; marrow (30 HU) is thus rendered as
  tissue, 0.2 % off. Each envelope part follows one bone's pose (foot part → calcaneus, shank
  part → tibia).
* The walkway is a lab-fixed carbon-fibre plate (exact slab chords), beads are exact spheres
  moving with their bone, rendered with fluence averaging over the pixel (the 2–5 % by which a
  steel bead's μ exceeds the bone it replaces is ignored).
* Attenuation coefficients of water, carbon and steel are taken at one effective energy
  (``energy_kev``, default 60 keV: μ_water = 0.0206 /mm, μ_steel = 0.95 /mm; NIST XCOM).

Line integrals go through each view's :class:`~core.synthetic.imaging.ImagingModel`; the noise of
frame ``i``, view ``v`` is seeded by ``(seed, i, v)``, so any frame renders identically alone or in
sequence. Renderers: Warp :class:`core.render.DRRRenderer` (``backend="warp"``, default device
CUDA when present) or the numpy :func:`core.render.render_reference` (``"reference"``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from .._validate import as_float_array, as_points
from ..geometry.camera import Rig
from ..render import DRRRenderer, HUTransfer, render_reference
from ..render.volume import CTVolume
from .analytic import attenuation_per_mm, bead_line_integrals, slab_line_integrals
from .imaging import ImagingModel
from .motion import stance_trajectories
from .phantoms import BONE_NAMES, SOFT_HU, foot_phantoms, soft_tissue_envelope
from .rig import FLOOR_Z_MM, foot_rig

__all__ = ["BeadSet", "BiplaneScene", "SceneRenderer", "excess_transfer", "make_foot_scene"]


def excess_transfer(base: HUTransfer, background_hu: float = SOFT_HU) -> HUTransfer:
    """``HU -> max(μ(HU) - μ(background_hu), 0)`` as a piecewise-linear :class:`HUTransfer`.

    Exact for the bilinear model and for ``curve`` tables (their knots, 0 HU and
    ``background_hu`` are all kept).
    """
    lo, hi = base.window if base.window is not None else (-1000.0, 3000.0)
    extra = list(base.curve[0]) if base.curve is not None else []
    knots = np.unique(np.clip([lo, -1000.0, 0.0, background_hu, hi, *extra], lo, hi))
    plain = HUTransfer(mu_water=base.mu_water, window=base.window, bone_slope=base.bone_slope,
                       curve=base.curve)
    mu = np.maximum(plain(knots) - plain(np.array([background_hu]))[0], 0.0)
    return HUTransfer(mu_water=base.mu_water, threshold=base.threshold, window=base.window,
                      curve=(tuple(knots.tolist()), tuple(mu.astype(float).tolist())))


@dataclass(frozen=True, eq=False)
class BeadSet:
    """Steel beads fixed in one bone (``bone`` index) or in the lab (``bone = -1``).

    ``centers (n, 3)`` are in the bone's CT frame (mm) or the lab; ``diameters`` in mm;
    ``mu`` in 1/mm.
    """

    centers: np.ndarray
    diameters: np.ndarray
    bone: int
    mu: float

    def __post_init__(self) -> None:
        c, _ = as_points(self.centers, "centers", 3)
        d = np.broadcast_to(as_float_array(self.diameters, "diameters"), (len(c),)).astype(float)
        object.__setattr__(self, "centers", c)
        object.__setattr__(self, "diameters", d)


@dataclass(frozen=True, eq=False)
class BiplaneScene:
    """A seeded biplane trial with ground truth at every frame.

    Parameters
    ----------
    rig : Rig
        The cameras (two for biplane).
    bones : sequence of CTVolume
        Bone volumes in HU (physical frame = the frame ``trajectories`` map from).
    trajectories : (n_bones, n_frames, 4, 4) array
        ``T_lab_from_bone`` of each bone at each frame.
    imaging : sequence of ImagingModel
        One image chain per view.
    beads : sequence of BeadSet
    tissue : sequence of CTVolume
        Soft-tissue parts in HU, rendered with the plain transfer.
    tissue_bones : sequence of int
        For each tissue part, the bone whose pose it follows.
    floor : (z_top_mm, thickness_mm, mu_per_mm) or None
        Lab-fixed walkway plate below ``z_top``.
    mu_water : float
        μ of water (1/mm) for the HU transfers.
    seed : int
        Seed of the per-frame noise.
    names : sequence of str, optional
        Bone names (default the volumes' names).
    """

    rig: Rig
    bones: tuple[CTVolume, ...]
    trajectories: np.ndarray
    imaging: tuple[ImagingModel, ...]
    beads: tuple[BeadSet, ...] = ()
    tissue: tuple[CTVolume, ...] = ()
    tissue_bones: tuple[int, ...] = ()
    floor: tuple[float, float, float] | None = None
    mu_water: float = 0.0206
    seed: int = 0
    names: tuple[str, ...] = ()
    _cache: dict = field(default_factory=dict, init=False, repr=False)

    def __post_init__(self) -> None:
        for nm in ("bones", "imaging", "beads", "tissue", "tissue_bones", "names"):
            object.__setattr__(self, nm, tuple(getattr(self, nm)))
        if not isinstance(self.rig, Rig):
            raise ValueError("rig: expected a core.geometry.Rig")
        nb = len(self.bones)
        if nb == 0 or not all(isinstance(b, CTVolume) and b.units == "HU" for b in self.bones):
            raise ValueError("bones: expected a non-empty sequence of CTVolume in HU")
        T = as_float_array(self.trajectories, "trajectories")
        if T.ndim != 4 or T.shape[0] != nb or T.shape[2:] != (4, 4) or T.shape[1] < 1:
            raise ValueError(f"trajectories: expected shape ({nb}, n_frames, 4, 4), got {T.shape}")
        T = T.copy()
        T.setflags(write=False)
        object.__setattr__(self, "trajectories", T)
        if len(self.imaging) != len(self.rig) or not all(isinstance(m, ImagingModel) for m in self.imaging):
            raise ValueError(f"imaging: expected {len(self.rig)} ImagingModel objects, one per view")
        if len(self.tissue_bones) != len(self.tissue) or any(not 0 <= b < nb for b in self.tissue_bones):
            raise ValueError("tissue_bones: expected one bone index (0..n_bones-1) per tissue volume")
        for bs in self.beads:
            if not (isinstance(bs, BeadSet) and -1 <= bs.bone < nb):
                raise ValueError("beads: expected BeadSet objects whose bone is -1 or a bone index")
        if not self.names:
            object.__setattr__(self, "names", tuple(b.name or f"bone{i}" for i, b in enumerate(self.bones)))
        elif len(self.names) != nb:
            raise ValueError(f"names: expected {nb} names, got {len(self.names)}")

    # ------------------------------------------------------------------ ground truth
    @property
    def n_frames(self) -> int:
        return int(self.trajectories.shape[1])

    @property
    def bone_transfer(self) -> HUTransfer:
        """Excess HU → μ transfer of the bone volumes (see the module docs)."""
        return excess_transfer(HUTransfer(mu_water=self.mu_water))

    @property
    def tissue_transfer(self) -> HUTransfer:
        return HUTransfer(mu_water=self.mu_water)

    def _frame(self, i: int) -> int:
        if int(i) != i or not -self.n_frames <= i < self.n_frames:
            raise ValueError(f"i: frame index out of range 0..{self.n_frames - 1}, got {i!r}")
        return int(i) % self.n_frames

    def poses(self, i: int) -> np.ndarray:
        """``(n_bones, 4, 4)`` ``T_lab_from_bone`` at frame ``i``."""
        return self.trajectories[:, self._frame(i)].copy()

    def bead_positions(self, i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Lab centres ``(n, 3)`` mm, diameters ``(n,)`` and μ ``(n,)`` of every bead at frame ``i``."""
        P = self.poses(i)
        cs, ds, ms = [np.zeros((0, 3))], [np.zeros(0)], [np.zeros(0)]
        for bs in self.beads:
            T = np.eye(4) if bs.bone < 0 else P[bs.bone]
            cs.append(bs.centers @ T[:3, :3].T + T[:3, 3])
            ds.append(bs.diameters)
            ms.append(np.full(len(bs.centers), bs.mu))
        return np.concatenate(cs), np.concatenate(ds), np.concatenate(ms)

    def bead_uv(self, i: int, *, distorted: bool = True) -> np.ndarray:
        """``(n_views, n_beads, 2)`` bead centre pixels (after the views' distortion by default)."""
        c, _, _ = self.bead_positions(i)
        out = []
        for cam, m in zip(self.rig, self.imaging, strict=True):
            uv = cam.project(c)
            out.append(m.distortion.forward(uv) if distorted and m.distortion is not None else uv)
        return np.stack(out)

    # ------------------------------------------------------------------ rendering
    def renderer(self, *, backend: str = "warp", device: str | None = None,
                 step_mm: float | None = None) -> SceneRenderer:
        """A :class:`SceneRenderer` (cached per backend/device/step for :meth:`render_frame`)."""
        key = (backend, device, step_mm)
        if key not in self._cache:
            self._cache[key] = SceneRenderer(self, backend=backend, device=device, step_mm=step_mm)
        return self._cache[key]

    def line_integrals(self, i: int, *, renderer: SceneRenderer | None = None) -> np.ndarray:
        """``(n_views, H, W)`` float32 total ``∫μ dl`` of frame ``i`` (bones, tissue, floor, beads)."""
        i = self._frame(i)
        r = renderer or self.renderer()
        if not isinstance(r, SceneRenderer) or r.scene is not self:
            raise ValueError("renderer: expected a SceneRenderer made from this scene "
                             "(scene.renderer(...)); a bare DRRRenderer lacks the tissue and transfers")
        L = r.volume_integrals(i).astype(np.float64)
        c, d, mu = self.bead_positions(i)
        for v, cam in enumerate(self.rig):
            if self.floor is not None:
                z, t, m = self.floor
                L[v] += slab_line_integrals(cam, (0.0, 0.0, z - t / 2), (0.0, 0.0, 1.0), t, m)
            if len(c):
                L[v] += bead_line_integrals(cam, c, d, mu, average="fluence")
        return L.astype(np.float32)

    def frame_rng(self, i: int, view: int) -> np.random.Generator:
        """The noise generator of frame ``i``, view ``view``."""
        return np.random.default_rng([int(self.seed), 0x5CE4E, self._frame(i), int(view)])

    def render_frame(self, i: int, *, renderer: SceneRenderer | None = None) -> np.ndarray:
        """``(n_views, H, W)`` uint16 camera frames of frame ``i`` (12-bit by default)."""
        L = self.line_integrals(i, renderer=renderer)
        return np.stack([m.apply(L[v], rng=self.frame_rng(i, v))
                         for v, m in enumerate(self.imaging)])


class SceneRenderer:
    """Renders a scene's bone and tissue volumes for any frame.

    Parameters
    ----------
    scene : BiplaneScene
    backend : {"warp", "reference"}
        :class:`core.render.DRRRenderer` or the slow numpy :func:`core.render.render_reference`.
    device : str, optional
        Warp device (default: CUDA when present, else CPU).
    step_mm : float, optional
        Ray step for the bones (default their smallest spacing); tissue uses its own spacing.
    """

    def __init__(self, scene: BiplaneScene, *, backend: str = "warp", device: str | None = None,
                 step_mm: float | None = None) -> None:
        if backend not in ("warp", "reference"):
            raise ValueError(f"backend: expected 'warp' or 'reference', got {backend!r}")
        self.scene, self.backend = scene, backend
        self._bone_mu = [b.to_attenuation(scene.bone_transfer) for b in scene.bones]
        self._tissue_mu = [t.to_attenuation(scene.tissue_transfer) for t in scene.tissue]
        self._step = step_mm
        if backend == "warp":
            self._bones = DRRRenderer(scene.rig, self._bone_mu, device=device, step_mm=step_mm)
            self._tissue = (DRRRenderer(scene.rig, self._tissue_mu, device=device)
                            if self._tissue_mu else None)

    def _reference(self, vols: Sequence[CTVolume], poses: np.ndarray, step) -> np.ndarray:
        out = np.zeros((len(self.scene.rig), *self.scene.rig[0].image_shape))
        for v, cam in enumerate(self.scene.rig):
            for vol, T in zip(vols, poses, strict=True):
                out[v] += render_reference(cam, vol, T, step_mm=step)
        return out

    def volume_integrals(self, i: int) -> np.ndarray:
        """``(n_views, H, W)`` float32 line integrals of all bone and tissue volumes at frame ``i``."""
        sc = self.scene
        P = sc.poses(i)
        Pt = P[list(sc.tissue_bones)] if sc.tissue else None
        if self.backend == "reference":
            L = self._reference(self._bone_mu, P, self._step)
            if sc.tissue:
                L += self._reference(self._tissue_mu, Pt, None)
            return L.astype(np.float32)
        L = self._bones.render(P[None], roi="full").numpy()[0].sum(axis=1)
        if self._tissue is not None:
            L = L + self._tissue.render(Pt[None], roi="full").numpy()[0].sum(axis=1)
        return L.astype(np.float32)



def _place_beads(phantom, n: int, diameter: float, g: np.random.Generator) -> np.ndarray:
    """``n`` bead centres inside the bone, >= 1.5 mm from its surface and spread apart."""
    lo, hi = phantom.volume.bounds()
    cand = g.uniform(lo, hi, size=(20000, 3))
    cand = cand[phantom.sdf(cand) < -(diameter / 2 + 1.5)]
    if len(cand) < n:
        raise ValueError(f"beads_per_bone: cannot fit {n} beads of {diameter} mm in {phantom.name}")
    chosen = [cand[0]]
    for _ in range(n - 1):  # farthest-point sampling: well-spread markers, as implanted for RSA
        d = np.min(np.linalg.norm(cand[:, None] - np.array(chosen)[None], axis=2), axis=1)
        chosen.append(cand[int(np.argmax(d))])
    return np.array(chosen)


def make_foot_scene(
    *,
    n_frames: int = 10,
    pixels: int = 512,
    seed: int = 0,
    spacing: float = 0.5,
    tissue_spacing: float = 2.0,
    names: Sequence[str] = BONE_NAMES,
    beads_per_bone: int = 3,
    bead_diameter_mm: float = 2.0,
    energy_kev: float = 60.0,
    imaging: str | Sequence[ImagingModel] = "fluoroscope",
    phase=(0.0, 0.9),
    floor_thickness_mm: float = 5.0,
    soft_tissue: bool = True,
    aperture_radius: float | None = 1.0,
) -> BiplaneScene:
    """The standard synthetic foot trial: every ingredient of :mod:`core.synthetic`, seeded.

    ``foot_rig`` (``pixels`` wide) + :func:`foot_phantoms` at ``spacing`` mm + a foot/shank
    soft-tissue envelope at ``tissue_spacing`` mm + ``beads_per_bone`` steel beads of
    ``bead_diameter_mm`` in each bone + a carbon-fibre walkway plate of ``floor_thickness_mm``
    (0 = none) + :func:`stance_trajectories` over ``phase`` of stance + per-view image chains
    (``"fluoroscope"`` = :meth:`ImagingModel.fluoroscope` with a round field of
    ``aperture_radius``, ``"ideal"`` = noise-free 12-bit, or one ImagingModel per view).
    Sub-seeds for the rig, motion, beads and imaging are spawned from ``seed``.
    """
    ss = np.random.SeedSequence(int(seed)).spawn(4)
    g_rig, g_motion, g_beads, g_img = (np.random.default_rng(s) for s in ss)
    rig = foot_rig(seed=g_rig, pixels=pixels)
    phantoms = foot_phantoms(names, spacing=spacing, seed=seed)
    traj = stance_trajectories(n_frames, names=names, seed=g_motion, phase=phase)
    steel = attenuation_per_mm("steel", energy_kev)
    beads = []
    if beads_per_bone:
        for b, ph in enumerate(phantoms):
            c = _place_beads(ph, int(beads_per_bone), bead_diameter_mm, g_beads)
            beads.append(BeadSet(c, np.full(len(c), bead_diameter_mm), b, steel))
    if isinstance(imaging, str):
        if imaging == "fluoroscope":
            models = tuple(ImagingModel.fluoroscope(c, rng=g_img, aperture_radius=aperture_radius)
                           for c in rig)
        elif imaging == "ideal":
            models = tuple(ImagingModel() for _ in rig)
        else:
            raise ValueError(f"imaging: expected 'fluoroscope', 'ideal' or ImagingModels, got {imaging!r}")
    else:
        models = tuple(imaging)
    tissue, tissue_bones = (), ()
    if soft_tissue and "calcaneus" in names and "tibia" in names:
        tissue = soft_tissue_envelope(spacing=tissue_spacing)
        tissue_bones = (list(names).index("calcaneus"), list(names).index("tibia"))
    floor = None
    if floor_thickness_mm > 0:
        floor = (FLOOR_Z_MM, float(floor_thickness_mm), attenuation_per_mm("carbon", energy_kev))
    return BiplaneScene(
        rig=rig, bones=tuple(p.volume for p in phantoms), trajectories=traj, imaging=models,
        beads=tuple(beads), tissue=tissue, tissue_bones=tissue_bones, floor=floor,
        mu_water=attenuation_per_mm("water", energy_kev), seed=int(seed), names=tuple(names),
    )
