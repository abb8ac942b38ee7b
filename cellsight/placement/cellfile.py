"""The cell file of a placement: the source cell file with its ``cameras`` replaced."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from cellsight.camera import Camera
from cellsight.model.yaml_input import read_cell_text, with_absolute_paths
from cellsight.runfolder.writes import write_file


def camera_entry(camera: Camera, name: str, reach: float = 1.0) -> dict:
    """A camera as a cell file's ``cameras`` entry: pixel intrinsics and a ``look_at`` pose
    (the point ``reach`` m along its optical axis as target, z up: the same rotation as
    :func:`~cellsight.geometry.transforms.look_at` gives a camera whose image x is
    horizontal)."""
    K, T = camera.K, camera.T_base_cam
    entry: dict = {"name": name, "width": camera.width, "height": camera.height,
                   "fx": float(K[0, 0]), "fy": float(K[1, 1]), "cx": float(K[0, 2]),
                   "cy": float(K[1, 2])}
    if camera.dist is not None:
        entry["dist"] = [float(d) for d in camera.dist]
    eye = T[:3, 3]
    entry["look_at"] = {"eye": [round(float(v), 6) for v in eye],
                        "target": [round(float(v), 6) for v in eye + reach * T[:3, 2]]}
    return entry


def write_cell_file(source: str, cameras: list[Camera], path: Path, note: str = "") -> Path:
    """Write the cell of file ``source`` with ``cameras`` (named ``cam1``, ``cam2``, ...)
    instead of its own, to ``path``; ``note``: a comment for its head."""
    src = Path(source)
    data = yaml.safe_load(read_cell_text(src))
    data = with_absolute_paths(data, src.resolve().parent)
    data["cameras"] = [camera_entry(cam, f"cam{i + 1}") for i, cam in enumerate(cameras)]
    head = [f"# {line}" for line in note.splitlines()]
    head.append(f"# The cell of {src} with cameras placed by cellsight place-cameras:")
    head += [f"#   cam{i + 1}: candidate {cam.name}, optical centre "
             f"{np.round(cam.center, 3).tolist()} m" for i, cam in enumerate(cameras)]
    path = Path(path)
    write_file(path, "\n".join(head) + "\n" + yaml.safe_dump(data, sort_keys=False, width=100))
    return path
