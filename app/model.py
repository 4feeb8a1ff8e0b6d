"""The viewer's evented model: the single source of truth the widgets subscribe to (Qt-free).

Following napari, widgets never own state: they read this model, subscribe to its events
(:mod:`psygnal` signals) and send *intents* back (``set_pose``, ``set_frame``, ``select``…).
Everything here is plain Python + numpy, so scripts and tests drive it without a window.

Poses are 4x4 ``T_lab_from_bone`` per bone and frame (mm). A pose edit is an undoable
command; consecutive edits of one drag are merged into a single undo step.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from psygnal import Signal

from core.geometry.camera import Rig
from core.render.volume import CTVolume

__all__ = ["BoneLayer", "PoseEdit", "ViewerModel"]

_COLORS = ((0.95, 0.35, 0.25), (0.25, 0.7, 0.95), (0.4, 0.85, 0.35), (0.95, 0.8, 0.2),
           (0.8, 0.4, 0.9), (0.3, 0.9, 0.8))


@dataclass(eq=False)
class BoneLayer:
    """One bone: its CT sub-volume, display properties, and a pose per frame.

    ``poses`` is ``(n_frames, 4, 4)``; ``keyframes`` marks frames whose pose the user set.
    """

    name: str
    volume: CTVolume
    poses: np.ndarray
    color: tuple[float, float, float] = (0.95, 0.35, 0.25)
    opacity: float = 0.6
    visible: bool = True
    locked: bool = False
    keyframes: set[int] = field(default_factory=set)
    mesh: tuple[np.ndarray, np.ndarray] | None = None  # (vertices (N, 3) mm, faces (M, 3))

    def __post_init__(self) -> None:
        P = np.asarray(self.poses, dtype=float)
        if P.ndim != 3 or P.shape[1:] != (4, 4):
            raise ValueError(f"poses: expected shape (n_frames, 4, 4), got {P.shape}")
        self.poses = P.copy()

    @property
    def centroid(self) -> np.ndarray:
        """Bone centroid in bone (CT physical) coordinates, mm."""
        c = getattr(self, "_centroid", None)
        if c is None:
            try:
                c = self.volume.centroid(threshold=200.0)
            except ValueError:
                c = self.volume.centroid(threshold=None)
            self._centroid = c
        return c


@dataclass(frozen=True)
class PoseEdit:
    """An undoable pose change of one bone at one frame."""

    bone: int
    frame: int
    before: np.ndarray
    after: np.ndarray
    label: str = "move"


class ViewerModel:
    """State of a viewer: rig, frames, bone layers, current frame, selection, undo history.

    Parameters
    ----------
    rig : Rig
        The calibrated cameras (one fluoroscope pane per camera).
    n_frames : int
        Trial length.
    frame_source : callable(view, frame) -> (H, W) array, optional
        Returns the fluoroscope image of a view at a frame (float or integer).
    """

    current_frame_changed = Signal(int)
    pose_changed = Signal(int, int)  # bone index, frame
    trajectory_changed = Signal(int)  # bone index: poses of many frames replaced
    layers_changed = Signal()
    layer_property_changed = Signal(int, str)  # bone index, property name
    selection_changed = Signal(int)  # bone index or -1
    history_changed = Signal()

    def __init__(self, rig: Rig, n_frames: int, *,
                 frame_source: Callable[[int, int], np.ndarray] | None = None) -> None:
        if not isinstance(rig, Rig):
            raise ValueError("rig: expected a core.geometry.Rig")
        if int(n_frames) < 1:
            raise ValueError(f"n_frames: expected >= 1, got {n_frames}")
        self.rig = rig
        self.n_frames = int(n_frames)
        self.frame_source = frame_source
        self.layers: list[BoneLayer] = []
        self._frame = 0
        self._selected = -1
        self._undo: list[PoseEdit] = []
        self._redo: list[PoseEdit] = []
        self._merge_key: object | None = None
        self.dirty = False

    # ------------------------------------------------------------------ layers
    def add_bone(self, name: str, volume: CTVolume, poses: np.ndarray | None = None, *,
                 color: Sequence[float] | None = None, mesh=None) -> int:
        """Add a bone layer (poses default to the identity for every frame); returns its index."""
        if any(layer.name == name for layer in self.layers):
            raise ValueError(f"name: a bone called {name!r} is already in the viewer")
        if poses is None:
            poses = np.tile(np.eye(4), (self.n_frames, 1, 1))
        poses = np.asarray(poses, dtype=float)
        if poses.shape == (4, 4):
            poses = np.tile(poses, (self.n_frames, 1, 1))
        if poses.shape != (self.n_frames, 4, 4):
            raise ValueError(f"poses: expected ({self.n_frames}, 4, 4) or (4, 4), got {poses.shape}")
        col = tuple(color) if color is not None else _COLORS[len(self.layers) % len(_COLORS)]
        self.layers.append(BoneLayer(name, volume, poses, color=col, mesh=mesh))
        self.layers_changed.emit()
        if self._selected < 0:
            self.select(len(self.layers) - 1)
        return len(self.layers) - 1

    def index(self, bone: int | str) -> int:
        if isinstance(bone, str):
            for i, layer in enumerate(self.layers):
                if layer.name == bone:
                    return i
            raise ValueError(f"bone: no bone named {bone!r} (have {[b.name for b in self.layers]})")
        if not 0 <= int(bone) < len(self.layers):
            raise ValueError(f"bone: index {bone} out of range for {len(self.layers)} bones")
        return int(bone)

    def set_layer_property(self, bone: int | str, name: str, value) -> None:
        """Change ``visible``, ``opacity``, ``color`` or ``locked`` of a bone layer."""
        i = self.index(bone)
        if name not in ("visible", "opacity", "color", "locked"):
            raise ValueError(f"name: expected visible, opacity, color or locked, got {name!r}")
        if name == "opacity" and not 0.0 <= float(value) <= 1.0:
            raise ValueError(f"opacity: expected a value in [0, 1], got {value}")
        setattr(self.layers[i], name, value)
        self.layer_property_changed.emit(i, name)

    # ------------------------------------------------------------------ frame / selection
    @property
    def current_frame(self) -> int:
        return self._frame

    def set_frame(self, frame: int) -> None:
        f = int(np.clip(int(frame), 0, self.n_frames - 1))
        if f != self._frame:
            self._frame = f
            self._merge_key = None
            self.current_frame_changed.emit(f)

    def step(self, delta: int) -> None:
        self.set_frame(self._frame + int(delta))

    @property
    def selected(self) -> int:
        return self._selected

    def select(self, bone: int | str | None) -> None:
        i = -1 if bone is None else self.index(bone)
        if i != self._selected:
            self._selected = i
            self._merge_key = None
            self.selection_changed.emit(i)

    def frame_image(self, view: int, frame: int | None = None) -> np.ndarray | None:
        if self.frame_source is None:
            return None
        return self.frame_source(view, self._frame if frame is None else int(frame))

    # ------------------------------------------------------------------ poses
    def pose(self, bone: int | str, frame: int | None = None) -> np.ndarray:
        """``T_lab_from_bone`` of a bone at a frame (default: the current frame); a copy."""
        i = self.index(bone)
        return self.layers[i].poses[self._frame if frame is None else int(frame)].copy()

    def poses_at(self, frame: int | None = None) -> np.ndarray:
        """``(n_bones, 4, 4)`` poses of every bone at a frame."""
        f = self._frame if frame is None else int(frame)
        return np.stack([layer.poses[f] for layer in self.layers]) if self.layers else np.zeros((0, 4, 4))

    def set_pose(self, bone: int | str, T, *, frame: int | None = None, label: str = "move",
                 merge: object | None = None, keyframe: bool = True) -> None:
        """Set a bone's pose (undoable). Edits with the same non-None ``merge`` key in a row
        (e.g. one mouse drag) form a single undo step. Locked bones refuse edits."""
        i = self.index(bone)
        layer = self.layers[i]
        if layer.locked:
            raise ValueError(f"bone: {layer.name} is locked")
        T = np.asarray(T, dtype=float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ValueError(f"T: expected a finite 4x4 pose, got shape {T.shape}")
        R = T[:3, :3]
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) <= 0:
            raise ValueError("T: expected a rigid transform (orthonormal rotation, det +1)")
        f = self._frame if frame is None else int(frame)
        before = layer.poses[f].copy()
        key = (merge, i, f) if merge is not None else None
        if key is not None and key == self._merge_key and self._undo:
            last = self._undo[-1]
            self._undo[-1] = PoseEdit(i, f, last.before, T.copy(), last.label)
        else:
            self._undo.append(PoseEdit(i, f, before, T.copy(), label))
        self._merge_key = key
        self._redo.clear()
        self._apply(i, f, T, keyframe)
        self.history_changed.emit()

    def end_interaction(self) -> None:
        """Close the current merge group (the next edit starts a new undo step)."""
        self._merge_key = None

    def _apply(self, i: int, f: int, T: np.ndarray, keyframe: bool) -> None:
        self.layers[i].poses[f] = T
        if keyframe:
            self.layers[i].keyframes.add(f)
        self.dirty = True
        self.pose_changed.emit(i, f)

    def set_trajectory(self, bone: int | str, poses: np.ndarray) -> None:
        """Replace a bone's whole trajectory (e.g. tracking results); clears the undo history."""
        i = self.index(bone)
        P = np.asarray(poses, dtype=float)
        if P.shape != (self.n_frames, 4, 4):
            raise ValueError(f"poses: expected ({self.n_frames}, 4, 4), got {P.shape}")
        self.layers[i].poses[:] = P
        self._undo.clear()
        self._redo.clear()
        self.dirty = True
        self.history_changed.emit()
        self.trajectory_changed.emit(i)
        self.pose_changed.emit(i, self._frame)

    # ------------------------------------------------------------------ undo / redo
    @property
    def can_undo(self) -> bool:
        return bool(self._undo)

    @property
    def can_redo(self) -> bool:
        return bool(self._redo)

    def _check_unlocked(self, e: PoseEdit, what: str) -> None:
        layer = self.layers[e.bone]
        if layer.locked:  # a tracking job or a batch writes its journal: the edit would reach it
            raise ValueError(f"bone: {layer.name} is locked: its edit at frame {e.frame} is not {what}")

    def undo(self) -> None:
        """Undo the last pose edit (refused, ``ValueError``, while its bone is locked)."""
        if not self._undo:
            return
        self._check_unlocked(self._undo[-1], "undone")
        e = self._undo.pop()
        self._redo.append(e)
        self._merge_key = None
        self._apply(e.bone, e.frame, e.before.copy(), keyframe=False)
        self.history_changed.emit()

    def redo(self) -> None:
        """Redo the last undone pose edit (refused, ``ValueError``, while its bone is locked)."""
        if not self._redo:
            return
        self._check_unlocked(self._redo[-1], "redone")
        e = self._redo.pop()
        self._undo.append(e)
        self._merge_key = None
        self._apply(e.bone, e.frame, e.after.copy(), keyframe=True)
        self.history_changed.emit()
