"""Forward kinematics of every link of the UR5 (example-robot-data's URDF), per call.

Forward kinematics of all links runs every frame (snapshot, CLIK at 500 Hz), so the URDF
chain's FK must be cheap. Compared, each from a joint vector to the poses of all 7 link frames
(the root and the 6 actuated joints' child links):

- cellsight ``SerialChain.fkine`` (numba kernel: fixed origin @ joint motion per joint), with
  its joint-vector check; the URDF chain on the hot path;
- a numpy serial chain built from the same parsed URDF (vectorised Rodrigues, batched
  ``origin @ motion``, then the running product), for comparison with the kernel;
- cellsight ``DHChain.fkine`` of the built-in R6AX (6 joints), for reference;
- Pinocchio (``pin``): ``forwardKinematics`` + ``updateFramePlacements``, and the same plus
  reading the 7 frames' ``homogeneous`` matrices (what a caller needs);
- yourdfpy: ``update_cfg`` + ``get_transform`` of each link (scene graph, no meshes).

Median of ``CALLS`` calls (µs), and the largest difference from Pinocchio's frames over the
sampled configurations (m for positions, rotation-matrix entries for rotations).
"""

from __future__ import annotations

import statistics
import time
from pathlib import Path

import numpy as np

from cellsight import load_cell
from cellsight.model.urdf import load_urdf_robot
from cellsight.model.urdf_files import resolve_uri

URDF = "package://example-robot-data/robots/ur_description/urdf/ur5_robot.urdf"
CALLS = 2000


def _median_us(fn, qs: np.ndarray) -> float:
    for q in qs[:20]:
        fn(q)
    times = []
    for q in qs:
        t0 = time.perf_counter()
        fn(q)
        times.append(time.perf_counter() - t0)
    return 1e6 * statistics.median(times)


def numpy_fkine(origins: np.ndarray, axes: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Frames 0..n of an all-revolute serial chain, numpy only (Rodrigues, vectorised)."""
    n = len(q)
    c, s = np.cos(q), np.sin(q)
    x, y, z = axes.T
    v = 1.0 - c
    M = np.zeros((n, 4, 4))
    M[:, 0, 0], M[:, 0, 1], M[:, 0, 2] = c + x * x * v, x * y * v - z * s, x * z * v + y * s
    M[:, 1, 0], M[:, 1, 1], M[:, 1, 2] = y * x * v + z * s, c + y * y * v, y * z * v - x * s
    M[:, 2, 0], M[:, 2, 1], M[:, 2, 2] = z * x * v - y * s, z * y * v + x * s, c + z * z * v
    M[:, 3, 3] = 1.0
    A = origins @ M
    T = np.empty((n + 1, 4, 4))
    T[0] = np.eye(4)
    for i in range(n):
        T[i + 1] = T[i] @ A[i]
    return T


def main() -> None:
    import pinocchio as pin
    import yourdfpy

    path = resolve_uri(URDF, {}, Path("."))
    robot = load_urdf_robot(path, "UR5")
    chain, names = robot.chain, robot.chain.link_names
    model = pin.buildModelFromUrdf(str(path))
    data = model.createData()
    ids = [model.getFrameId(n) for n in names]
    urdf = yourdfpy.URDF.load(str(path), build_scene_graph=True, load_meshes=False)
    rng = np.random.default_rng(0)
    qs = np.array([chain.random_q(rng) for _ in range(CALLS)])

    def pin_fk(q):
        pin.forwardKinematics(model, data, q)
        pin.updateFramePlacements(model, data)

    def pin_frames(q):
        pin_fk(q)
        return np.array([data.oMf[i].homogeneous for i in ids])

    def urdfpy_frames(q):
        urdf.update_cfg(q)
        return np.array([urdf.get_transform(n) for n in names])

    dh = load_cell().robot("R6AX").chain
    dh_qs = np.array([dh.random_q(rng) for _ in range(CALLS)])
    rows = [
        ("cellsight SerialChain.fkine (numba)", _median_us(chain.fkine, qs), chain.fkine),
        ("numpy serial chain", _median_us(lambda q: numpy_fkine(chain.origins, chain.axes, q),
                                          qs), lambda q: numpy_fkine(chain.origins, chain.axes, q)),
        ("cellsight DHChain.fkine (R6AX, ref.)", _median_us(dh.fkine, dh_qs), None),
        ("pinocchio FK + frame placements", _median_us(pin_fk, qs), None),
        ("pinocchio, + 7 frames as 4x4", _median_us(pin_frames, qs), pin_frames),
        ("yourdfpy update_cfg + get_transform", _median_us(urdfpy_frames, qs[:300]),
         urdfpy_frames),
    ]
    print(f"UR5 forward kinematics of all {len(names)} link frames, median of {CALLS} calls")
    print(f"{'method':40s} {'us/call':>9s} {'max |diff| vs pin':>18s}")
    for label, us, fn in rows:
        worst = 0.0 if fn is None else max(np.abs(fn(q) - pin_frames(q)).max() for q in qs[:200])
        diff = "" if fn is None else f"{worst:.1e}"
        print(f"{label:40s} {us:9.2f} {diff:>18s}")


if __name__ == "__main__":
    main()
