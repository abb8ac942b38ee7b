"""Each candidate camera's view of the task: which features it sees at each frame, exactly,
and how much they tell about the part's pose.

Per frame, all candidates at once: the features are moved to the base frame, projected into
every candidate (the template's lens model), and those in the image are tested against the
cell's solids with the predictor's static object hierarchies
(:meth:`~cellsight.occlusion.object_bvh.ObjectBVH.occluders`; self-, mutual and
robot occlusions, exact). The pose information of candidate c at frame k is the Fisher
information of the part's pose (base-frame translation, m, and a small rotation about the
part's origin, rad) from its visible features, each measured with ``sigma_px`` (px) of noise
per coordinate::

    I_kc = sum_{f visible} J_f^T J_f / sigma_px^2,  J_f = d pixel_f / d (t, theta)  (2 x 6)

(the pinhole Jacobian of the projection times ``R_cam_base [I, -[p_f - t_part]x]``). Frames
are scored in chunks on the sweep engine (:func:`cellsight.sweep.engine.map_jobs`: in this process,
on a local pool or a Dask cluster).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from cellsight.camera import Camera
from cellsight.model.cell import Cell
from cellsight.model.loader import load_cell
from cellsight.occlusion.backends import visibility_predictor
from cellsight.occlusion.predictor import VisibilityPredictor
from cellsight.placement._information_kernel import pose_information
from cellsight.placement.task import TaskFrames
from cellsight.sweep.engine import map_jobs

_LOADED: dict[str, tuple[Cell, VisibilityPredictor]] = {}  # per process: cell file -> predictor


@dataclass(frozen=True)
class CandidateScores:
    """``cameras`` (C); ``visible`` (N, C, F) bool: feature f seen by candidate c at frame k;
    ``info`` (N, C, 6, 6) float32: the pose information (module docstring; translation
    first, 1/m^2, then rotation, 1/rad^2)."""

    cameras: list[Camera]
    visible: np.ndarray
    info: np.ndarray

    @property
    def pairs(self) -> int:
        """Frame x candidate pairs scored."""
        return self.visible.shape[0] * self.visible.shape[1]


class CandidateRig(NamedTuple):
    """The candidates of one intrinsics ``template``: their ``R_cb`` = ``R_cam_base``
    (C, 3, 3), ``t_cb`` = ``t_cam_base`` (C, 3) and optical ``centers`` (C, 3), base frame,
    m."""

    template: Camera
    R_cb: np.ndarray
    t_cb: np.ndarray
    centers: np.ndarray

    @classmethod
    def of(cls, template: Camera, T_base_cams: np.ndarray) -> CandidateRig:
        R_cb = np.ascontiguousarray(T_base_cams[:, :3, :3].transpose(0, 2, 1))
        centers = np.ascontiguousarray(T_base_cams[:, :3, 3])
        return cls(template, R_cb, -np.einsum("cij,cj->ci", R_cb, centers), centers)


def frame_views(predictor: VisibilityPredictor, rig: CandidateRig, joints: dict, part: str,
                T_part: np.ndarray, openings: dict, sigma_px: float):
    """One frame: (C, F) visible and (C, 6, 6) information for the candidates of ``rig``."""
    template, R_cb, t_cb, centers = rig
    cell = predictor.cell
    snapshot = cell.snapshot(joints, {part: T_part}, openings)
    points = cell.workpiece(part).feature_points @ T_part[:3, :3].T + T_part[:3, 3]
    pc = np.matmul(R_cb, points.T).transpose(0, 2, 1) + t_cb[:, None, :]
    C, F = pc.shape[:2]
    px = template.project_camera(pc.reshape(-1, 3)).reshape(C, F, 2)
    inside = (pc[..., 2] > 0) & template.in_image(px.reshape(-1, 2)).reshape(C, F)
    cams, feats = np.nonzero(inside)
    starts = np.searchsorted(cams, np.arange(C + 1))
    visible = np.zeros((C, F), dtype=bool)
    visible[cams, feats] = predictor.occluders(snapshot, centers, starts, points[feats]) < 0
    info = np.empty((C, 6, 6))
    pose_information(R_cb, np.ascontiguousarray(pc), visible,
                     np.ascontiguousarray(points - T_part[:3, 3]), float(template.K[0, 0]),
                     float(template.K[1, 1]), info)
    return visible, info / sigma_px**2


def _predictor(cell_file: str) -> VisibilityPredictor:
    if cell_file not in _LOADED:
        cell = load_cell(cell_file)
        _LOADED[cell_file] = (cell, visibility_predictor(cell))
    return _LOADED[cell_file][1]


def score_chunk(job: tuple) -> tuple[np.ndarray, np.ndarray]:
    """A chunk of frames (a sweep-engine job): ``(cell_file, template, T_base_cams (C, 4, 4),
    joints, part, part_poses, openings, sigma_px)`` -> visible (n, C, F), info (n, C, 6, 6)."""
    cell_file, template, T_base_cams, joints, part, poses, openings, sigma_px = job
    predictor = _predictor(cell_file)
    rig = CandidateRig.of(template, T_base_cams)
    out_vis, out_info = [], []
    for k in range(len(poses)):
        vis, info = frame_views(predictor, rig, {r: q[k] for r, q in joints.items()}, part,
                                poses[k],
                                {r: float(o[k]) for r, o in openings.items()
                                 if np.isfinite(o[k])}, sigma_px)
        out_vis.append(vis)
        out_info.append(info.astype(np.float32))
    return np.stack(out_vis), np.stack(out_info)


def score_candidates(cell: Cell, task: TaskFrames, cameras: list[Camera],
                     sigma_px: float = 0.5, chunk: int = 100, workers: int = 1,
                     scheduler=None, progress: bool = True) -> CandidateScores:
    """Score every candidate at every frame of the task (module docstring). Every candidate
    must share the first one's intrinsics, size and distortion."""
    template = cameras[0]
    for cam in cameras:
        if (cam.width, cam.height) != (template.width, template.height) or not (
                np.array_equal(cam.K, template.K) and np.array_equal(cam.dist5, template.dist5)):
            raise ValueError(f"score_candidates: camera {cam.name} has other intrinsics than "
                             f"{template.name}")
    T = np.stack([c.T_base_cam for c in cameras])
    jobs = [(cell.source, template, T, {r: q[rows] for r, q in task.joints.items()}, task.part,
             task.part_poses[rows], {r: o[rows] for r, o in task.openings.items()}, sigma_px)
            for rows in task.chunks(chunk)]
    parts: list = [None] * len(jobs)
    for i, result in map_jobs(score_chunk, jobs, workers=workers, scheduler=scheduler,
                              progress=progress, label="scoring candidates"):
        parts[i] = result
    return CandidateScores(list(cameras), np.concatenate([p[0] for p in parts]),
                           np.concatenate([p[1] for p in parts]))
