"""The MuJoCo model (MJCF text) generated from a :class:`~cellsight.model.Cell`.

Every cell object becomes a mesh geom named like the object (``R7AX.link3``, ``part``,
``table.2``) on a body whose frame *is* the object's frame, so that the body poses equal
``cell.snapshot(...).poses``:

- robot ``R``: body ``R/0`` at ``T_base_robot`` (frame 0, holds the base's solids), bodies
  ``R/1`` .. ``R/n`` at the chain's frames (standard DH: joint ``R/q<i>`` on the axis z_{i-1};
  URDF: at the joint origins, joint ``R/q<i>`` on the URDF axis through the body's origin; a
  hinge for a revolute joint, a slide for a prismatic one), body ``R/tool`` at
  ``T_flange_tool`` (palm geoms, site ``R/tcp``), jaw bodies ``R/jaw1``, ``R/jaw2`` at
  their joints' zero, sliding along their axes by their joint values (joints ``R/jaw1``,
  ``R/jaw2``; the second a mimic of the first: :class:`~cellsight.model.robot.Jaw`);
- workpiece ``P``: a mocap body ``P`` (driven kinematically by the world);
- static object ``S``: a fixed body ``S`` at ``T_base_obj``;
- an intruder the cell file does not know (:mod:`cellsight.world.intruders`): a mocap body and
  geom named like it (``unknown.box``);
- a floor plane ``floor`` at z = 0, lights, and one fixed camera per cell camera;
- a printed plate on a robot's flange (a calibration board, :mod:`cellsight.world.board_plate`):
  a textured mesh geom ``R.board`` on body ``R/n``, its texture ``R.board.png`` an asset to
  give MuJoCo (:func:`~cellsight.world.board_plate.plate_files`).

Geom groups: 0 static objects, intruders and floor, 1 robots, 2 workpieces. The jointed bodies
get a nominal inertia (1 kg). Every geom may collide (``contype`` and ``conaffinity`` 1).

By default the world is kinematic: the model is never integrated, and contacts only serve
MuJoCo's collision detection to report them (:mod:`cellsight.world.contacts`); no contact force
acts, and the body pairs of ``exclude`` are left out of the detection (contacts the report
leaves out anyway). With a servo of MuJoCo's actuators (``ServoParams.mujoco``,
:mod:`cellsight.world.servo`), the robots' joints get their rotor inertia (``armature``) and a
position actuator ``R/a<i>`` each, the robots' bodies are gravity compensated
(``gravcomp``), the integrator is ``implicitfast``, and contacts push back, except between the
body pairs of ``exclude`` (a robot's own bodies, its mounts, the jaws and the parts they
straddle: :func:`excluded_pairs`). Vertices and
poses are written with full float64 precision (MuJoCo stores mesh vertices as float32, about
1e-8 m here).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from itertools import combinations
from xml.sax.saxutils import quoteattr

import mujoco
import numpy as np

from cellsight.camera import Camera
from cellsight.geometry.polyhedron import Polyhedron
from cellsight.model import Cell, CellObject
from cellsight.model.cell import ObjectFrame
from cellsight.model.robot import Robot
from cellsight.rates import CONTROL_HZ
from cellsight.world.board_plate import Plate, plate_assets, plate_geom
from cellsight.world.intruders import Intruder
from cellsight.world.servo import ARMATURE_KG, ARMATURE_KG_M2, ServoParams, actuator_gains

GROUP_STATIC, GROUP_ROBOT, GROUP_PART = 0, 1, 2
_FLIP_YZ = np.diag([1.0, -1.0, -1.0])  # OpenCV camera axes <-> MuJoCo camera axes

# Grey levels (B/W cameras): a bright part on darker surroundings, so its edges stand out.
_GREY = {"workpiece": 0.92, "link": 0.62, "tool": 0.38, "static": 0.34}
_INTRUDER_GREY = 0.5
_FLOOR_GREY = 0.12


def _num(values) -> str:
    """Numbers as MJCF text with full float64 precision."""
    return " ".join(f"{float(v):.17g}" for v in np.ravel(values))


def _quat(R: np.ndarray) -> np.ndarray:
    """MuJoCo quaternion (w, x, y, z) of a rotation matrix."""
    q = np.empty(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(R, dtype=float).ravel())
    return q


def _pose_attrs(T: np.ndarray) -> str:
    return f'pos="{_num(T[:3, 3])}" quat="{_num(_quat(T[:3, :3]))}"'


def body_name(robot: str, frame: int | str) -> str:
    """Name of a robot body: ``R/<i>`` for DH frame i, ``R/tool``, ``R/jaw1``, ``R/jaw2``."""
    return f"{robot}/{frame}"


def joint_name(robot: str, i: int) -> str:
    """Name of the MuJoCo joint of robot joint ``i`` (1-based, like the DH frames)."""
    return f"{robot}/q{i}"


def tcp_site_name(robot: str) -> str:
    return f"{robot}/tcp"


def mjcf_camera(camera: Camera, size: tuple[int, int] | None = None) -> str:
    """MJCF ``<camera>`` element reproducing an OpenCV pinhole camera (undistorted part).

    Frames: OpenCV cameras look along +z with x right and y down; MuJoCo cameras look along -z
    with x right and y up, so ``R_base_mjcam = R_base_cvcam @ diag(1, -1, -1)``.

    Intrinsics: the camera's ``focalpixel`` is (fx, fy) and its ``principalpixel`` is the
    principal point's offset from the image centre; MuJoCo's vertical field of view then
    follows from fy (``fovy = 2 atan(H / (2 fy))``). OpenCV puts the centre of the top-left
    pixel at (0, 0), so the image centre is ((W - 1) / 2, (H - 1) / 2); MuJoCo's offset is the
    image centre minus the principal point in both axes, ``((W - 1) / 2 - cx, (H - 1) / 2 - cy)``
    (checked on MuJoCo's frustum and on rendered images by the tests). ``sensorsize`` is set to
    the resolution (one length unit per pixel) only to switch MuJoCo's intrinsics on; ``ipd`` is
    0 so that the stereo eyes coincide with the camera.

    ``size`` = (width, height) renders at another resolution with the intrinsics scaled to it
    (:meth:`Camera.scaled_K <cellsight.camera.Camera.scaled_K>`, same field of view); default:
    the camera's own size.
    """
    w, h = size if size is not None else (camera.width, camera.height)
    K = camera.scaled_K((w, h))
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    R = camera.T_base_cam[:3, :3] @ _FLIP_YZ
    return (
        f"<camera name={quoteattr(camera.name)} pos=\"{_num(camera.T_base_cam[:3, 3])}\" "
        f'quat="{_num(_quat(R))}" ipd="0" resolution="{w} {h}" sensorsize="{w} {h}" '
        f'focalpixel="{_num([fx, fy])}" '
        f'principalpixel="{_num([(w - 1) / 2 - cx, (h - 1) / 2 - cy])}"/>'
    )


def _mesh_asset(name: str, solid: Polyhedron) -> str:
    return (
        f'<mesh name={quoteattr(name)} vertex="{_num(solid.vertices)}" '
        f'face="{" ".join(map(str, solid.triangles().ravel()))}" inertia="shell"/>'
    )


def _geom(obj: CellObject, group: int) -> str:
    g = _GREY[obj.kind]
    return (
        f'<geom name={quoteattr(obj.name)} type="mesh" mesh={quoteattr(obj.name)} '
        f'group="{group}" rgba="{g} {g} {g} 1"/>'
    )


def _frame_body(frame: ObjectFrame) -> str:
    """Name of the body of a cell object's frame (module docstring)."""
    if frame.kind == "link":
        return body_name(frame.owner, frame.index)
    if frame.kind == "palm":
        return body_name(frame.owner, "tool")
    if frame.kind == "jaw":
        return body_name(frame.owner, f"jaw{frame.index + 1}")
    return frame.owner  # a workpiece's or static object's body is named like it


def object_bodies(cell: Cell) -> tuple[str, ...]:
    """Name of the body that carries each cell object (the object's frame is the body's frame),
    in ``cell.objects`` order (from ``cell.frames``)."""
    return tuple(_frame_body(frame) for frame in cell.frames)


_INERTIAL = '<inertial pos="0 0 0" mass="1" diaginertia="0.01 0.01 0.01"/>'
_GROUPS = {"link": GROUP_ROBOT, "tool": GROUP_ROBOT, "workpiece": GROUP_PART}


def _geoms_and_assets(cell: Cell) -> tuple[dict[str, list[str]], list[str]]:
    """Every object's geom, grouped by the name of its body, and its mesh asset."""
    geoms: dict[str, list[str]] = {}
    assets = []
    for obj, body in zip(cell.objects, object_bodies(cell), strict=True):
        geoms.setdefault(body, []).append(_geom(obj, _GROUPS.get(obj.kind, GROUP_STATIC)))
        assets.append(_mesh_asset(obj.name, obj.solid))
    return geoms, assets


def _armature(prismatic: bool) -> float:
    return ARMATURE_KG if prismatic else ARMATURE_KG_M2


def _link_bodies(robot: Robot, geoms: dict[str, list[str]], dynamic: bool) -> list[str]:
    """Opening tags, joints and geoms of the frame bodies ``R/1`` .. ``R/n`` (DH or URDF chain,
    from its :meth:`joint_placements`), nested (the caller closes them); ``dynamic``: with
    gravity compensation and the joints' armature (module docstring)."""
    xml = []
    chain = robot.chain
    A0, joint_pos, joint_axis = chain.joint_placements()
    gravcomp = ' gravcomp="1"' if dynamic else ""
    for i, (A, prismatic) in enumerate(zip(A0, chain.prismatic, strict=True), start=1):
        # The joint's origin and axis in frame i (the child body): for DH, z of frame i-1.
        kind = "slide" if prismatic else "hinge"
        armature = f' armature="{_armature(prismatic):g}"' if dynamic else ""
        xml.append(f"<body name={quoteattr(body_name(robot.name, i))} {_pose_attrs(A)}"
                   f"{gravcomp}>")
        xml.append(_INERTIAL)
        xml.append(
            f"<joint name={quoteattr(joint_name(robot.name, i))} type=\"{kind}\" "
            f'pos="{_num(joint_pos[i - 1])}" axis="{_num(joint_axis[i - 1])}" '
            f'range="{_num(chain.qlim[i - 1])}"{armature}/>'
        )
        xml += geoms.get(body_name(robot.name, i), [])
    return xml


def _tool_body(robot: Robot, geoms: dict[str, list[str]], dynamic: bool) -> list[str]:
    """The tool body ``R/tool`` (palm geoms, TCP site) with its two sliding jaw bodies."""
    tool = robot.tool
    gravcomp = ' gravcomp="1"' if dynamic else ""
    xml = [
        f"<body name={quoteattr(body_name(robot.name, 'tool'))} "
        f"{_pose_attrs(tool.T_flange_tool)}{gravcomp}>"
    ]
    xml += geoms.get(body_name(robot.name, "tool"), [])  # a URDF hand's palm is a link
    site = quoteattr(tcp_site_name(robot.name))
    xml.append(f'<site name={site} pos="{_num(tool.tcp)}"/>')
    travel = np.sort(np.array([tool.jaw_values(0.0), tool.jaw_values(tool.max_opening)]),
                     axis=0)
    for k, jaw in enumerate(tool.jaws):
        name = body_name(robot.name, f"jaw{k + 1}")
        axis = jaw.T_tool_jaw0[:3, :3].T @ jaw.axis  # in the jaw's own frame
        xml.append(f"<body name={quoteattr(name)} {_pose_attrs(jaw.T_tool_jaw0)}{gravcomp}>"
                   f"{_INERTIAL}")
        xml.append(
            f'<joint name={quoteattr(name)} type="slide" axis="{_num(axis)}" '
            f'range="{_num(travel[:, k])}"/>'
        )
        xml += geoms[name]
        xml.append("</body>")
    xml.append("</body>")
    return xml


def _robot_body(robot: Robot, geoms: dict[str, list[str]], dynamic: bool) -> str:
    """The robot's body tree: base ``R/0``, DH frame bodies, tool and jaws."""
    base = body_name(robot.name, 0)
    xml = [f"<body name={quoteattr(base)} {_pose_attrs(robot.T_base_robot)}>"]
    xml += geoms.get(base, [])
    xml += _link_bodies(robot, geoms, dynamic)
    if robot.tool is not None:
        xml += _tool_body(robot, geoms, dynamic)
    xml.append("</body>" * (robot.n_joints + 1))
    return "\n".join(xml)


def _intruder_body(intruder: Intruder) -> str:
    g = _INTRUDER_GREY
    name = quoteattr(intruder.name)
    return (f'<body name={name} mocap="true" {_pose_attrs(intruder.pose(0.0))}>'
            f'<geom name={name} type="mesh" mesh={name} group="{GROUP_STATIC}" '
            f'rgba="{g} {g} {g} 1"/></body>')


def _world_bodies(cell: Cell, geoms: dict[str, list[str]], dynamic: bool) -> list[str]:
    """Robots' body trees, workpieces' mocap bodies and static objects' fixed bodies."""
    world = [_robot_body(robot, geoms, dynamic) for robot in cell.robots]
    for part in cell.workpieces:
        world.append(
            f'<body name={quoteattr(part.name)} mocap="true" {_pose_attrs(part.T_base_part)}>'
            + "".join(geoms[part.name])
            + "</body>"
        )
    for obj in cell.static:
        world.append(
            f"<body name={quoteattr(obj.name)} {_pose_attrs(obj.T_base_obj)}>"
            + "".join(geoms[obj.name])
            + "</body>"
        )
    return world


def link_inertia(model: mujoco.MjModel, data: mujoco.MjData,
                 cell: Cell) -> dict[str, np.ndarray]:
    """Robot name -> the inertia (kg m^2, kg for a prismatic joint) each of its joints moves
    beyond its rotor in the model's state: the diagonal of MuJoCo's joint-space mass matrix
    less the joints' armature (the links, tool and jaws beyond the joint)."""
    mujoco.mj_forward(model, data)
    M = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, M)
    out = {}
    for robot in cell.robots:
        dofs = [model.jnt_dofadr[model.joint(joint_name(robot.name, i)).id]
                for i in range(1, robot.n_joints + 1)]
        out[robot.name] = np.diag(M)[dofs] - model.dof_armature[dofs]
    return out


def _dynamics(cell: Cell, servo: ServoParams | None, exclude: Sequence[tuple[str, str]],
              links: Mapping[str, np.ndarray] | None) -> tuple[str, str]:
    """The ``<actuator>`` section of a world of MuJoCo's actuators (module docstring; else
    empty), its gains set for each joint's rotor and ``links`` (:func:`link_inertia`; none:
    the rotor's alone), and the ``<contact>`` section excluding the body pairs ``exclude``."""
    pairs = [f"<exclude body1={quoteattr(a)} body2={quoteattr(b)}/>" for a, b in exclude]
    contacts = f"<contact>{chr(10).join(pairs)}</contact>" if pairs else ""
    if servo is None or not servo.mujoco:
        return "", contacts
    actuators = []
    for robot in cell.robots:
        moved = (links or {}).get(robot.name, np.zeros(robot.n_joints))
        for i, prismatic in enumerate(robot.chain.prismatic, start=1):
            kp, kv, limit = actuator_gains(servo, _armature(prismatic) + float(moved[i - 1]))
            force = (f' forcelimited="true" forcerange="{-limit:.17g} {limit:.17g}"'
                     if np.isfinite(limit) else "")
            actuators.append(f"<position name={quoteattr(f'{robot.name}/a{i}')} "
                             f"joint={quoteattr(joint_name(robot.name, i))} kp=\"{kp:.17g}\" "
                             f'kv="{kv:.17g}"{force}/>')
    return f"<actuator>{chr(10).join(actuators)}</actuator>", contacts


def excluded_pairs(cell: Cell, mounts: Iterable[tuple[str, str]] = ()) -> list[tuple[str, str]]:
    """The body pairs whose contacts exert no force in a world of MuJoCo's actuators: every
    pair of one robot's bodies (its solids overlap at the joints by construction), each jaw
    with each workpiece (the jaws straddle a part, and MuJoCo's convex hull of a non-convex
    part swallows them), and the pairs ``mounts`` (:func:`~cellsight.world.contacts.mount_bodies`:
    a base on the floor, a carriage in its track)."""
    pairs: list[tuple[str, str]] = []
    for robot in cell.robots:
        bodies = [body_name(robot.name, i) for i in range(robot.n_joints + 1)]
        if robot.tool is not None:
            jaws = [body_name(robot.name, "jaw1"), body_name(robot.name, "jaw2")]
            bodies += [body_name(robot.name, "tool")] + jaws
            pairs += [(jaw, part.name) for jaw in jaws for part in cell.workpieces]
        pairs += list(combinations(bodies, 2))
    return pairs + [pair for pair in mounts if pair not in pairs]


def cell_mjcf(cell: Cell, render_size: tuple[int, int] | None = None,
              intruders: tuple[Intruder, ...] = (), servo: ServoParams | None = None,
              exclude: Sequence[tuple[str, str]] = (),
              plates: Mapping[str, Plate] | None = None,
              links: Mapping[str, np.ndarray] | None = None) -> str:
    """MJCF text of the cell and the ``intruders`` it does not know (see the module docstring
    for names and frames); ``plates``: robot name -> the plate on its flange.

    ``render_size`` = (width, height) of the rendered images (default: each camera's own).
    ``servo``: the joints' servo; with ``servo.mujoco`` the model is MuJoCo's dynamics, its
    contacts pushing back; never between the body pairs of ``exclude`` (module docstring), the
    actuators' gains set for each joint's rotor and ``links`` (:func:`link_inertia`).
    """
    dynamic = servo is not None and servo.mujoco
    geoms, assets = _geoms_and_assets(cell)
    assets += [_mesh_asset(i.name, i.solid) for i in intruders]
    for robot, plate in (plates or {}).items():
        flange = body_name(robot, cell.robot(robot).n_joints)
        geoms.setdefault(flange, []).append(plate_geom(robot, GROUP_ROBOT))
        assets += plate_assets(robot, plate)
    world = _world_bodies(cell, geoms, dynamic) + [_intruder_body(i) for i in intruders]
    actuators, contacts = _dynamics(cell, servo, exclude, links)
    sizes = [render_size or (c.width, c.height) for c in cell.cameras] or [(640, 480)]
    offw, offh = max(s[0] for s in sizes), max(s[1] for s in sizes)
    cameras = [mjcf_camera(c, render_size) for c in cell.cameras]
    return f"""<mujoco model={quoteattr(cell.name)}>
<compiler angle="radian" inertiafromgeom="false" autolimits="true"/>
<option timestep="{1.0 / CONTROL_HZ:g}"{' integrator="implicitfast"' if dynamic else ""}/>
<visual>
  <global offwidth="{offw}" offheight="{offh}"/>
  <quality offsamples="4" shadowsize="0"/>
  <headlight ambient="0.22 0.22 0.22" diffuse="0.38 0.38 0.38" specular="0 0 0"/>
  <map znear="0.005" zfar="40"/>
</visual>
<default><geom contype="1" conaffinity="1"/></default>
<asset>
{chr(10).join(assets)}
</asset>
<worldbody>
<light name="key" directional="true" castshadow="false" dir="0.35 0.25 -1"
       diffuse="0.5 0.5 0.5" specular="0.05 0.05 0.05"/>
<light name="fill" directional="true" castshadow="false" dir="-0.6 -0.4 -0.5"
       diffuse="0.18 0.18 0.18" specular="0 0 0"/>
<geom name="floor" type="plane" size="6 6 0.1" group="{GROUP_STATIC}"
      rgba="{_FLOOR_GREY} {_FLOOR_GREY} {_FLOOR_GREY} 1"/>
{chr(10).join(cameras)}
{chr(10).join(world)}
</worldbody>
{actuators}
{contacts}
</mujoco>
"""
