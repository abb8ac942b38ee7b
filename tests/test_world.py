"""The simulated cell (cellsight.world): kinematics against fkine, rendering against
Camera.project, ray-cast truth against an independent check, conveyor, grasping, tasks."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import trimesh

from cellsight import load_cell
from cellsight.camera import Camera
from cellsight.geometry.polyhedron import box
from cellsight.geometry.transforms import (
    invert_pose,
    make_pose,
    pose_from_xyz_rpy,
    transform_points,
)
from cellsight.model import Cell, StaticObject
from cellsight.model.grasp import JawPads, PartSection
from cellsight.visibility import STATUS_BEHIND, STATUS_INSIDE, STATUS_OUTSIDE
from cellsight.world import ConveyorPath, Waypoint, World
from cellsight.world.imperfections import Imperfections
from cellsight.world.mjcf import mjcf_camera
from cellsight.world.world import Hands


@pytest.fixture(scope="module")
def cell() -> Cell:
    return load_cell()


def _with_cameras(cell: Cell, cameras: list[Camera]) -> Cell:
    return Cell(cell.name, cell.robots, cell.workpieces, cell.static, cameras)


def _shifted_cameras(cell: Cell) -> Cell:
    """The cell with off-centre principal points and non-square pixels."""
    cams = []
    for c in cell.cameras:
        K = c.K.copy()
        K[0, 2] += 25.0
        K[1, 2] -= 18.0
        K[1, 1] *= 1.03
        cams.append(Camera(K, c.width, c.height, c.T_base_cam, name=c.name))
    return _with_cameras(cell, cams)


def _distorted_cameras(cell: Cell) -> Cell:
    """The cell with lens distortion (k1, k2, p1, p2, k3)."""
    dist = [-0.45, 0.3, 0.002, -0.0015, 0.0]
    return _with_cameras(cell, [Camera(c.K, c.width, c.height, c.T_base_cam, dist, c.name)
                                for c in cell.cameras])


def _rot_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


# --- kinematics --------------------------------------------------------------------------------


def test_body_poses_agree_with_fkine_at_random_configurations(cell):
    world = World(cell)
    rng = np.random.default_rng(7)
    worst = 0.0
    for _ in range(250):
        q = {r.name: r.chain.random_q(rng) for r in cell.robots}
        part = pose_from_xyz_rpy(rng.uniform(-1, 1, 3), rng.uniform(-np.pi, np.pi, 3))
        world.place_part("part", part)
        world.step(q, {r.name: rng.uniform(0.0, r.tool.max_opening) for r in cell.robots})
        joints = world.true_joints()
        for name in q:
            np.testing.assert_array_equal(joints[name], q[name])
        snap = cell.snapshot(joints, world.true_part_poses(), world.jaw_openings())
        np.testing.assert_allclose(world.true_part_poses()["part"], part, atol=1e-12)
        worst = max(worst, float(np.abs(world.truth.object_poses() - snap.poses).max()))
    assert worst < 1e-6
    # the jaws really moved during the run, so the jaw bodies were checked at many openings
    assert 0.0 < world.jaw_openings()["R7AX"] < cell.robot("R7AX").tool.max_opening


def test_set_points_are_clipped_to_joint_limits(cell):
    world = World(cell)
    robot = cell.robot("R6AX")
    world.step({"R6AX": robot.chain.qlim[:, 1] + 0.5}, {})
    np.testing.assert_array_equal(world.true_joints()["R6AX"], robot.chain.qlim[:, 1])
    with pytest.raises(ValueError, match="6 finite values"):
        world.step({"R6AX": np.zeros(5)}, {})


# --- cameras and rendering ---------------------------------------------------------------------


@pytest.mark.parametrize("size", [None, (640, 480)])
def test_mjcf_camera_frustum_reproduces_the_intrinsics(cell, size):
    import mujoco

    for cam in _shifted_cameras(cell).cameras + cell.cameras:
        model = mujoco.MjModel.from_xml_string(
            f"<mujoco><worldbody>{mjcf_camera(cam, size)}</worldbody></mujoco>"
        )
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        scene = mujoco.MjvScene(model, 10)
        view = mujoco.MjvCamera()
        view.type, view.fixedcamid = mujoco.mjtCamera.mjCAMERA_FIXED, 0
        mujoco.mjv_updateScene(
            model, data, mujoco.MjvOption(), None, view, mujoco.mjtCatBit.mjCAT_ALL, scene
        )
        gl = mujoco.mjv_averageCamera(scene.camera[0], scene.camera[1])  # the mono camera
        w, h = size or (cam.width, cam.height)
        K, n = cam.scaled_K((w, h)), gl.frustum_near
        # OpenGL window x in [0, w] is OpenCV u + 0.5; window y from the bottom is h - v - 0.5
        left, right = -n * (K[0, 2] + 0.5) / K[0, 0], n * (w - 0.5 - K[0, 2]) / K[0, 0]
        bottom, top = -n * (h - 0.5 - K[1, 2]) / K[1, 1], n * (K[1, 2] + 0.5) / K[1, 1]
        got = [gl.frustum_center - gl.frustum_width, gl.frustum_center + gl.frustum_width,
               gl.frustum_bottom, gl.frustum_top]
        np.testing.assert_allclose(got, [left, right, bottom, top], rtol=1e-5)
        np.testing.assert_allclose(gl.pos, cam.center, atol=1e-6)
        np.testing.assert_allclose(gl.forward, cam.T_base_cam[:3, 2], atol=1e-6)
        np.testing.assert_allclose(gl.up, -cam.T_base_cam[:3, 1], atol=1e-6)


def _edge_line(image: np.ndarray, a: np.ndarray, b: np.ndarray):
    """Sub-pixel line of the image edge near the projected segment a-b: at 25 stations along
    it, at least 6 px from its ends (away from the other edges there), where the profile across
    it crosses halfway between its two plateaus. None when the edge is faint or the profile is
    not a single step."""
    length = np.linalg.norm(b - a)
    d = (b - a) / length
    normal = np.array([-d[1], d[0]])
    offsets = np.arange(-4.0, 4.0 + 1e-9, 0.25)
    found = []
    for s in np.linspace(6.0 / length, 1.0 - 6.0 / length, 25):
        q = (a + s * (b - a)) + offsets[:, None] * normal
        profile = cv2.remap(
            image, q[:, 0].astype(np.float32)[None], q[:, 1].astype(np.float32)[None],
            cv2.INTER_LINEAR,
        ).ravel()
        lo, hi = np.median(profile[:4]), np.median(profile[-4:])
        if abs(hi - lo) < 25:
            return None
        x = (profile - 0.5 * (lo + hi)) * np.sign(hi - lo)
        k = np.flatnonzero((x[:-1] < 0) & (x[1:] >= 0))
        if len(k) != 1:
            return None
        k = int(k[0])
        off = offsets[k] + 0.25 * (-x[k] / (x[k + 1] - x[k]))
        found.append(a + s * (b - a) + off * normal)
    pts = np.array(found)
    center = pts.mean(axis=0)
    return center, np.linalg.svd(pts - center)[2][0]


def _measured_corners(image, camera: Camera, solid, T_base_part, visible) -> dict[int, float]:
    """Corner -> distance (px) between the intersection of its two measured image edges and
    ``camera.project`` of the corner."""
    V = transform_points(T_base_part, solid.vertices)
    uv = camera.project(V)
    normals = solid.normals @ T_base_part[:3, :3].T
    faces_of: dict[tuple[int, int], list[int]] = {}
    for k, face in enumerate(solid.faces):
        for i in range(len(face)):
            faces_of.setdefault(tuple(sorted((face[i], face[i - 1]))), []).append(k)
    lines = {}
    for (i, j), faces in faces_of.items():
        drawn = any(normals[k] @ (camera.center - V[i]) > 0 for k in faces)
        if visible[i] and visible[j] and drawn and np.linalg.norm(uv[i] - uv[j]) > 20:
            line = _edge_line(image.astype(np.float32), uv[i], uv[j])
            if line is not None:
                lines[(i, j)] = line
    errors = {}
    for v in range(len(V)):
        incident = [line for edge, line in lines.items() if v in edge]
        pairs = [(abs(a[1][0] * b[1][1] - a[1][1] * b[1][0]), a, b)
                 for n, a in enumerate(incident) for b in incident[n + 1:]]
        pairs = [p for p in pairs if p[0] > 0.7]  # edges at more than ~45 degrees
        if pairs:
            _, (c1, d1), (c2, d2) = max(pairs, key=lambda p: p[0])
            t = np.linalg.solve(np.column_stack([d1, -d2]), c2 - c1)
            errors[v] = float(np.linalg.norm(c1 + t[0] * d1 - uv[v]))
    return errors


@pytest.mark.parametrize("variant", ["built-in", "shifted principal point, 640x480", "distorted"])
def test_rendered_part_corners_lie_on_their_projections(cell, variant):
    world_cell, size = {
        "built-in": (cell, None),
        "shifted principal point, 640x480": (_shifted_cameras(cell), (640, 480)),
        "distorted": (_distorted_cameras(cell), None),
    }[variant]
    world = World(world_cell, render_size=size)
    solid = cell.workpiece("part").solid
    errors = []
    for xyz_rpy in ([0.6, 0.0, 0.62, 0, 0, 0.35], [0.7, 0.05, 0.62, 0, 0, -0.6],
                    [0.65, -0.05, 0.70, 0.3, -0.2, 1.2]):
        T = pose_from_xyz_rpy(xyz_rpy[:3], xyz_rpy[3:])
        world.place_part("part", T)
        images = world.render()
        visible = [view.visible for view in world.true_views()["part"]]
        for c, cam in enumerate(world_cell.cameras):
            w, h = size or (cam.width, cam.height)
            seen = Camera(cam.scaled_K((w, h)), w, h, cam.T_base_cam, cam.dist, cam.name)
            assert images[c].shape == (h, w) and images[c].dtype == np.uint8
            errors += _measured_corners(images[c], seen, solid, T, visible[c]).values()
    assert len(errors) >= 24  # at least 4 corners measured per image on average
    assert np.median(errors) < 0.2 and max(errors) < 0.6, sorted(errors)[-5:]


def test_images_are_grayscale_with_the_part_standing_out(cell):
    world = World(cell)
    first, second = world.render(), world.render()
    assert len(first) == len(cell.cameras)
    T = cell.workpiece("part").T_base_part
    for c, cam in enumerate(cell.cameras):
        np.testing.assert_array_equal(first[c], second[c])
        top = cam.project(transform_points(T, [[0.035, 0.0, 0.03]]))[0]  # middle of one arm
        near = cam.project(transform_points(T, [[0.0, -0.12, 0.0]]))  # conveyor beside it
        u, v = np.round(top).astype(int)
        un, vn = np.round(near[0]).astype(int)
        assert int(first[c][v, u]) > int(first[c][vn, un]) + 60  # bright part, darker conveyor


# --- truth -------------------------------------------------------------------------------------


def _segment_hits_box(p: np.ndarray, q: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> bool:
    """Slab test: does the segment p-q cross the axis-aligned box [lo, hi]?"""
    d = q - p
    t0, t1 = 0.0, 1.0
    for k in range(3):
        if abs(d[k]) < 1e-15:
            if not lo[k] <= p[k] <= hi[k]:
                return False
            continue
        a, b = sorted(((lo[k] - p[k]) / d[k], (hi[k] - p[k]) / d[k]))
        t0, t1 = max(t0, a), min(t1, b)
    return t0 <= t1


def test_ray_truth_matches_an_independent_check_with_a_blocking_box(cell):
    part = cell.workpiece("part")
    cam = cell.cameras[0]
    P = transform_points(part.T_base_part, part.feature_points)
    target = P[[8, 15]].mean(axis=0)  # between two top corners
    center = cam.center + 0.55 * (target - cam.center)
    size = np.array([0.06, 0.06, 0.06])
    blocker = StaticObject("blocker", (box("blocker", size, center),), np.eye(4))
    blocked_cell = Cell(cell.name, cell.robots, cell.workpieces, [*cell.static, blocker],
                        cell.cameras)
    world = World(blocked_cell)
    view = world.true_views()["part"][0]
    visible, occluders = view.visible, view.reason

    mesh = trimesh.Trimesh(transform_points(part.T_base_part, part.solid.vertices),
                           part.solid.triangles(), process=False)
    by_box = np.array([_segment_hits_box(cam.center, p, center - size / 2, center + size / 2)
                       for p in P])
    vec = P - cam.center
    dist = np.linalg.norm(vec, axis=1)
    hits, rays, _ = mesh.ray.intersects_location(
        np.repeat(cam.center[None], len(P), 0), vec / dist[:, None], multiple_hits=True
    )
    by_self = np.zeros(len(P), dtype=bool)
    for hit, ray in zip(hits, rays, strict=True):
        if np.linalg.norm(hit - cam.center) < dist[ray] - 1e-3:
            by_self[ray] = True
    expected = cam.sees(P) & ~by_box & ~by_self
    assert by_box.sum() >= 2 and (~by_box & ~by_self).sum() >= 4 and by_self.sum() >= 1
    np.testing.assert_array_equal(visible, expected)
    for j in range(len(P)):
        want = "blocker" if by_box[j] else "self" if by_self[j] else ""
        assert occluders[j] == want, (j, occluders[j], want)
    # the second camera does not look through the box
    np.testing.assert_array_equal(world.true_views()["part"][1].visible,
                                  World(cell).true_views()["part"][1].visible)


def test_features_outside_the_image_or_behind_are_marked(cell):
    world = World(cell)
    cam = cell.cameras[0]
    behind = cam.T_base_cam @ make_pose(None, (0.0, 0.0, -1.0))
    world.place_part("part", behind)
    view = world.true_views()["part"][0]
    assert set(view.reason) == {"behind"} and set(view.status) == {STATUS_BEHIND}
    assert np.isnan(view.pixels).all()
    aside = cam.T_base_cam @ make_pose(None, (3.0, 0.0, 2.0))
    world.place_part("part", aside)
    view = world.true_views()["part"][0]
    assert set(view.reason) == {"outside"} and set(view.status) == {STATUS_OUTSIDE}
    assert not view.visible.any() and (view.occluder == -1).all()


def _first_hits(world: World, cam: Camera, points: np.ndarray) -> list[str]:
    """The name of the geom each ray from the camera to a point hits first before it (more
    than 2 mm short of it), '' if none: the old ``true_occluders`` answer, cast here."""
    import mujoco

    model, data = world.scene.model, world.scene.data
    world.scene.sync()
    names = []
    for p in points:
        vec = p - cam.center
        length = float(np.linalg.norm(vec))
        geom = np.array([-1], dtype=np.int32)
        d = mujoco.mj_ray(model, data, cam.center, vec / length, None, 1, -1, geom)
        names.append(model.geom(int(geom[0])).name if 0 <= d < length - 2e-3 else "")
    return names


def test_true_views_answer_as_the_predictors_do(cell):
    """The truth is a CameraVisibility per camera: pixels are the camera's projection, the
    occluder indexes ``object_labels`` (the cell objects' labels, then 'floor'), and each
    feature's reason is the label of the object whose geom the ray hits first ('self' for the
    part), as the world's old ``true_visibility``/``true_occluders`` answered. Cases: the part
    turned on the conveyor, held in R7AX's jaws at HOME, and (a cell without static objects)
    under the floor, seen through it by camera 1."""
    part = cell.workpiece("part")
    bare = World(Cell(cell.name, cell.robots, cell.workpieces, [], cell.cameras))
    cases = [(World(cell), part.T_base_part @ make_pose(_rot_z(a))) for a in (0.0, 1.0, 2.5)]
    held = World(cell)
    away = part.T_base_part[:3, 3] - cell.cameras[0].center  # along camera 1's line of sight
    below = make_pose(None, away * (part.T_base_part[2, 3] + 0.05) / -away[2]) @ part.T_base_part
    cases += [(held, _part_in_gripper(held, cell, np.eye(4))), (bare, below)]
    labels = {o.name: o.label for o in cell.objects}
    seen: set[str] = set()
    for world, T in cases:
        world.place_part("part", T)
        P = transform_points(T, part.feature_points)
        for cam, view in zip(cell.cameras, world.true_views()["part"], strict=True):
            assert view.camera == cam.name and view.object_labels[-1] == "floor"
            assert view.part_object == cell.object_index("part")
            np.testing.assert_allclose(view.pixels, cam.project(P))
            inside = cam.sees(P)
            np.testing.assert_array_equal(view.status == STATUS_INSIDE, inside)
            hits = _first_hits(world, cam, P)
            want = ["self" if h == "part" else labels.get(h, h) if i else ""
                    for h, i in zip(hits, inside, strict=True)]
            got = [r if i else "" for r, i in zip(view.reason, inside, strict=True)]
            assert got == want, (cam.name, got, want)
            np.testing.assert_array_equal(view.visible, inside & (np.array(hits) == ""))
            seen.update(got)
    assert {"self", "floor", "R7AX.gripper", ""} <= seen, seen


# --- conveyor ----------------------------------------------------------------------------------


def _run_until(world: World, t: float, **step) -> None:
    while world.time < t - 1e-9:
        world.step(**step)


def test_conveyor_moves_the_part_along_its_path_at_its_speed(cell):
    path = ConveyorPath([(0.40, -0.05), (0.60, -0.05), (0.60, 0.05)], speed=0.05, t_start=0.2)
    world = World(cell, conveyor=path)
    nominal = cell.workpiece("part").T_base_part
    for t, xy in ((0.1, (0.40, -0.05)), (2.2, (0.50, -0.05)), (3.2, (0.55, -0.05)),
                  (5.2, (0.60, 0.0)), (7.0, (0.60, 0.05))):
        _run_until(world, t)
        T = world.true_part_poses()["part"]
        np.testing.assert_allclose(T[:2, 3], xy, atol=1e-9)
        np.testing.assert_allclose(T[2, 3], nominal[2, 3], atol=1e-12)
        np.testing.assert_allclose(T[:3, :3], nominal[:3, :3], atol=1e-12)
    stopped = World(cell, conveyor=ConveyorPath(path.points, speed=0.05, t_start=0.2, t_stop=1.0))
    _run_until(stopped, 2.0)
    np.testing.assert_allclose(stopped.true_part_poses()["part"][:2, 3], (0.44, -0.05), atol=1e-9)
    still = World(cell, conveyor=ConveyorPath.still())
    _run_until(still, 0.5)
    np.testing.assert_allclose(still.true_part_poses()["part"], nominal, atol=1e-12)


# --- grasping ----------------------------------------------------------------------------------


def _part_in_gripper(world: World, cell: Cell, offset: np.ndarray) -> np.ndarray:
    """Place the part so that its grasp pose is ``offset`` (in the TCP frame) from R7AX's TCP
    at HOME; returns the part pose."""
    robot = cell.robot("R7AX")
    T = robot.tcp_pose(robot.home) @ offset @ invert_pose(world.grippers.grasp_pose("part"))
    world.place_part("part", T)
    return T


def _close(world: World, seconds: float = 0.4) -> None:
    home = world.cell.robot("R7AX").home
    _run_until(world, world.time + seconds, setpoints={"R7AX": home}, gripper={"R7AX": 0.0})


def test_grasp_engages_at_the_grasp_pose_carries_and_releases_the_part(cell):
    world = World(cell)
    robot = cell.robot("R7AX")
    placed = _part_in_gripper(world, cell, np.eye(4))
    _close(world)
    assert world.jaws_closed_on_part("R7AX") and world.grasp("R7AX") is not None
    np.testing.assert_allclose(world.true_part_poses()["part"], placed, atol=1e-12)  # no push
    width = world.jaw_openings()["R7AX"]
    assert 0.02 < width < robot.tool.max_opening
    q = robot.home + np.array([0.3, 0.2, 0.1, -0.1, 0.3, 0.2, -0.4])
    for s in np.linspace(0, 1, 50):
        world.step({"R7AX": robot.home + s * (q - robot.home)}, {})
        T_tcp_part = invert_pose(robot.tcp_pose(world.true_joints()["R7AX"]))
        np.testing.assert_allclose(T_tcp_part @ world.true_part_poses()["part"],
                                   invert_pose(robot.tcp_pose(robot.home)) @ placed, atol=1e-9)
    assert world.jaw_openings()["R7AX"] == width
    world.step({"R7AX": q}, {"R7AX": robot.tool.max_opening})
    assert world.grasp("R7AX") is None and not world.jaws_closed_on_part("R7AX")
    released = world.true_part_poses()["part"]
    _run_until(world, world.time + 1.0, setpoints={"R7AX": q})
    rest = world.true_part_poses()["part"]
    np.testing.assert_allclose(rest[:3, :3], released[:3, :3], atol=1e-12)
    np.testing.assert_allclose(rest[:2, 3], released[:2, 3], atol=1e-12)
    bottom = transform_points(rest, cell.workpiece("part").solid.vertices)[:, 2].min()
    supports = [transform_points(snap_T, o.solid.vertices)[:, 2].max()
                for o, snap_T in zip(cell.objects, cell.snapshot().poses, strict=True)
                if o.kind == "static"]
    assert rest[2, 3] < released[2, 3] - 0.05  # it fell...
    assert min(abs(bottom - z) for z in supports) < 1e-6  # ...onto the table or the conveyor
    _run_until(world, world.time + 0.2, setpoints={"R7AX": robot.home})
    np.testing.assert_allclose(world.true_part_poses()["part"], rest, atol=1e-12)


def test_a_part_let_go_pressed_into_the_table_rests_on_its_top(cell):
    """A held part put down 8 mm too low (its bottom inside the table's slab: a kinematic part
    goes where the jaws take it) rests on the table's top once let go, as the tracker's
    landing (``cellsight.model.landing``) has it; it did fall 22 mm further into the slab."""
    from cellsight.model.landing import Landing

    world = World(cell)
    table = next(o for o in cell.static if o.name == "table")
    top = transform_points(table.T_base_obj, table.solids[0].vertices)[:, 2].max()
    part = cell.workpiece("part")
    T = pose_from_xyz_rpy([0.88, -0.28, top - 0.008], [0.0, 0.0, 0.4])
    world.place_part("part", T)
    world.parts.release("part")
    _run_until(world, world.time + 0.3, setpoints={})
    rest = world.true_part_poses()["part"]
    bottom = transform_points(rest, part.solid.vertices)[:, 2].min()
    assert bottom == pytest.approx(top, abs=1e-6)
    np.testing.assert_allclose(rest[:2, 3], T[:2, 3], atol=1e-12)
    model = Landing(cell.static).rest_pose(part.solid.vertices, T)
    np.testing.assert_allclose(model, rest, atol=1e-6)


def test_jaws_centre_a_slightly_offset_part_and_grasp_it(cell):
    world = World(cell)
    placed = _part_in_gripper(world, cell, make_pose(None, (0.0, 0.005, 0.0)))
    _close(world)
    assert world.grasp("R7AX") is not None
    robot = cell.robot("R7AX")
    centred = robot.tcp_pose(robot.home) @ invert_pose(world.grippers.grasp_pose("part"))
    moved = world.true_part_poses()["part"]
    np.testing.assert_allclose(moved[:3, 3], centred[:3, 3], atol=1e-6)
    assert np.linalg.norm(moved[:3, 3] - placed[:3, 3]) == pytest.approx(0.005, abs=1e-6)


@pytest.mark.parametrize(
    "offset",
    [make_pose(None, (0.02, 0.0, 0.0)), make_pose(_rot_z(math.radians(12.0)))],
    ids=["2 cm along the jaws", "12 degrees about the approach axis"],
)
def test_grasp_does_not_engage_out_of_tolerance(cell, offset):
    world = World(cell)
    _part_in_gripper(world, cell, offset)
    _close(world)
    assert world.jaws_closed_on_part("R7AX") and world.grasp("R7AX") is None
    before = world.true_part_poses()["part"]
    robot = cell.robot("R7AX")
    away = robot.home + 0.1 * np.eye(7)[0]  # 10 cm along the track, jaws still closed
    _run_until(world, world.time + 0.3, setpoints={"R7AX": away})
    np.testing.assert_allclose(world.true_part_poses()["part"], before, atol=1e-12)


def test_jaws_move_at_finite_speed_and_close_fully_on_nothing(cell):
    world = World(cell, hands=Hands(jaw_speed=0.2))
    _run_until(world, 0.1, gripper={"R7AX": 0.0})
    assert world.jaw_openings()["R7AX"] == pytest.approx(0.09 - 0.02, abs=1e-9)
    assert not world.jaws_closed_on_part("R7AX")
    _run_until(world, 0.6)
    assert world.jaw_openings()["R7AX"] == pytest.approx(0.0, abs=1e-12)
    assert not world.jaws_closed_on_part("R7AX") and world.grasp("R7AX") is None


# --- the second arm's task, joint measurements -------------------------------------------------


def test_second_arm_follows_its_timed_waypoints(cell):
    robot = cell.robot("R6AX")
    qa = robot.home + np.array([0.4, 0.2, -0.2, 0.3, -0.3, 0.5])
    qb = qa + np.array([-0.2, 0.1, 0.1, 0.0, 0.2, -0.4])
    world = World(cell, tasks={"R6AX": [Waypoint(0.1, qa), Waypoint(0.2, qb, smooth=False)]})
    checks = {0.02: robot.home + (qa - robot.home) * (0.2**3 * (10 - 15 * 0.2 + 6 * 0.2**2)),
              0.05: (robot.home + qa) / 2, 0.1: qa, 0.15: (qa + qb) / 2, 0.3: qb}
    for t, want in checks.items():
        _run_until(world, t)
        np.testing.assert_allclose(world.true_joints()["R6AX"], want, atol=1e-12)
    with pytest.raises(ValueError, match="own task"):
        world.step({"R6AX": qb}, {})


def test_joint_measurements_are_noisy_and_seeded(cell):
    noisy = Imperfections(noise_rad=1e-3, noise_m=1e-3)
    a, b = World(cell, seed=3, errors=noisy), World(cell, seed=3, errors=noisy)
    samples = np.array([a.measured_joints()["R7AX"] for _ in range(2000)])
    np.testing.assert_array_equal(b.measured_joints()["R7AX"], samples[0])
    err = samples - a.true_joints()["R7AX"]
    assert np.all(np.abs(err.mean(axis=0)) < 1e-4)
    np.testing.assert_allclose(err.std(axis=0), 1e-3, rtol=0.1)


def test_jaw_pad_section_matches_dense_ray_sampling(cell):
    """The exact extent of the part's material inside a jaw pad's bar, against rays along y
    through a dense grid of the bar (a lower bound that converges to it)."""
    solid = cell.workpiece("part").solid
    section = PartSection(solid)
    pad = JawPads.of(cell.robot("R7AX").tool).jaw1
    rng = np.random.default_rng(11)
    xs, zs = np.linspace(pad[0], pad[1], 60), np.linspace(pad[2], pad[3], 60)
    grid = np.array([[x, -1.0, z] for x in xs for z in zs])
    checked = 0
    for _ in range(12):
        T = pose_from_xyz_rpy(rng.normal([0.0, 0.0, 0.13], 0.015), rng.normal(0.0, 0.4, 3))
        mesh = trimesh.Trimesh(transform_points(T, solid.vertices), solid.triangles(),
                               process=False)
        hits, _, _ = mesh.ray.intersects_location(grid, np.tile([0.0, 1.0, 0.0], (len(grid), 1)))
        exact = section.y_range(T, pad)
        if len(hits) == 0:
            assert exact is None
            continue
        checked += 1
        assert exact[0] <= hits[:, 1].min() + 1e-9 and exact[1] >= hits[:, 1].max() - 1e-9
        assert hits[:, 1].min() - exact[0] < 2e-3 and exact[1] - hits[:, 1].max() < 2e-3
    assert checked >= 8
