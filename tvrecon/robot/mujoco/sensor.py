"""TactileSensor: an EIP pad on any MuJoCo geom or body, pressed by MuJoCo's own contacts.

Attach it like TACTO's ``add_body``: give the model, its data and the pad's geom (or body)::

    import mujoco
    from tvrecon.robot.mujoco.sensor import TactileSensor, sense_pads

    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    left = TactileSensor(model, data, geom="left_pad", normal_axis=(0, -1, 0), up_axis=(0, 0, 1), pad="digit")
    right = TactileSensor(model, data, geom="right_pad", normal_axis=(0, 1, 0), up_axis=(0, 0, 1),
                          simulator=left.sim, pad=left.pad)
    mujoco.mj_step(model, data)
    readings = sense_pads([left, right])   # one batched EIP solver call for both pads in contact
    readings[0].image, readings[0].force_field, readings[0].patch, readings[0].rgb(), readings[0].markers()

Each call reads ``data.contact`` for the pad's geoms (normal force from ``mj_contactForce``, penetration from
``dist``), picks the touched geom with the largest force and presses *that geom's own surface*: the model's mesh
asset (``mesh_vert`` / ``mesh_face``; the full mesh, not the convex hull MuJoCo collides with) or a trimesh of the
primitive (box, sphere, capsule, cylinder, ellipsoid, plane), at its current pose. The press, its caching and the
batching are :class:`tvrecon.robot.pad_sensor.PadSensor`'s, shared with the pybullet ``TactileFinger``. Without contact
the reading is the rest reading (no simulation).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import mujoco
import numpy as np
import trimesh

from tvrecon.robot.pad_config import PadConfig
from tvrecon.robot.pad_reading import ContactPoint
from tvrecon.robot.pad_sensor import PadSensor

__all__ = ["TactileSensor", "geom_mesh"]

_PLANE_EXTENT = 2.0  # metres: an infinite MuJoCo plane is pressed as a slab this wide
_PLANE_THICKNESS = 0.05


def _id(model: mujoco.MjModel, kind: mujoco.mjtObj, ref: int | str, what: str) -> int:
    if isinstance(ref, str):
        i = mujoco.mj_name2id(model, kind, ref)
        if i < 0:
            raise ValueError(f"the model has no {what} named {ref!r}")
        return int(i)
    n = model.ngeom if kind == mujoco.mjtObj.mjOBJ_GEOM else model.nbody
    if not 0 <= int(ref) < n:
        raise ValueError(f"{what} id {ref} out of range: the model has {n} {what}s")
    return int(ref)


def geom_mesh(model: mujoco.MjModel, geom: int | str) -> trimesh.Trimesh:
    """The surface of a MuJoCo geom in the geom's own frame (metres).

    Mesh geoms give their mesh asset's vertices and faces (``model.mesh_vert`` / ``mesh_face``, already in the geom
    frame); primitives give a trimesh of their size: box (half sizes), sphere, capsule and cylinder (radius, half
    length along z), ellipsoid, plane (a ``_PLANE_EXTENT`` m slab below z = 0 for an infinite plane).

    Raises:
        ValueError: an unknown geom, or a type without a surface here (height fields, SDF geoms).
    """
    g = _id(model, mujoco.mjtObj.mjOBJ_GEOM, geom, "geom")
    t = mujoco.mjtGeom(int(model.geom_type[g]))
    size = np.asarray(model.geom_size[g], dtype=np.float64)
    G = mujoco.mjtGeom
    if t == G.mjGEOM_MESH:
        m = int(model.geom_dataid[g])
        va, vn = int(model.mesh_vertadr[m]), int(model.mesh_vertnum[m])
        fa, fn = int(model.mesh_faceadr[m]), int(model.mesh_facenum[m])
        verts = np.asarray(model.mesh_vert[va : va + vn], dtype=np.float64)
        faces = np.asarray(model.mesh_face[fa : fa + fn], dtype=np.int64)
        return trimesh.Trimesh(verts, faces, process=False)
    if t == G.mjGEOM_BOX:
        return trimesh.creation.box(extents=2.0 * size)
    if t == G.mjGEOM_SPHERE:
        return trimesh.creation.icosphere(subdivisions=3, radius=size[0])
    if t == G.mjGEOM_CAPSULE:
        return trimesh.creation.capsule(height=2.0 * size[1], radius=size[0], count=[24, 24])
    if t == G.mjGEOM_CYLINDER:
        return trimesh.creation.cylinder(radius=size[0], height=2.0 * size[1], sections=48)
    if t == G.mjGEOM_ELLIPSOID:
        s = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
        s.apply_scale(size)
        return s
    if t == G.mjGEOM_PLANE:
        ext = [2 * size[0] if size[0] > 0 else _PLANE_EXTENT, 2 * size[1] if size[1] > 0 else _PLANE_EXTENT]
        slab = trimesh.creation.box(extents=[ext[0], ext[1], _PLANE_THICKNESS])
        slab.apply_translation([0.0, 0.0, -_PLANE_THICKNESS / 2])
        return slab
    raise ValueError(f"geom {g} has type {t.name}: the tactile pad can press meshes and primitive geoms only")


class TactileSensor(PadSensor):
    """An EIP pad on a MuJoCo geom (or on all geoms of a body).

    Args:
        model, data: the MuJoCo model and its data (read at each :meth:`sense`; step the data yourself).
        geom: the pad's geom (id or name); its frame is the pad's link frame. Give this or ``body``.
        body: the pad's body (id or name): contacts of any of its geoms count, the body frame is the link frame.
        pad: a :class:`~tvrecon.robot.pad_config.PadConfig`, a ``tvrecon.sim.SensorConfig`` (2 cm wide) or a real-sensor
            preset name ("digit", "gelsight_mini", "gelsight_r15", "tactip"); None = ``PadConfig()``.
        normal_axis: (3,) press direction in the link frame (out of the pad, towards what it touches).
        up_axis: (3,) the image rows' axis in the link frame.
        pad_center: (3,) centre of the pad face in the link frame (the press is centred there); None: on the
            force-weighted contact point.
        objects: geoms (ids or names) the pad can feel; None = every geom not on the pad's own body.
        simulator: share one (e.g. ``other_sensor.sim``) so the pads' presses run in one batched solver call.
        n_grid: grid cells of the press domain when ``pad`` is a preset name.
        name: label used in logs.
        use_penetration: also take MuJoCo's penetration as a lower bound of the press depth. Off by default: MuJoCo's
            soft contacts overlap by what ``solref`` / ``solimp`` allow (1.1-1.3 mm under a 20 N squeeze with the
            gripper's ``solref="0.01 1"``, ``benchmarks/bench_mujoco_agreement.py``), a constraint setting rather
            than the gel's give, so the depth is the pad's elastic give under MuJoCo's contact force
            (``force / pad.stiffness``), as with pybullet's nearly rigid contacts.

    Meshes given to :meth:`attach_object` are in the *geom's* frame: MuJoCo recentres a mesh asset on its centre of
    mass and turns it to its principal axes (``geom_mesh`` returns it so).
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        data: mujoco.MjData,
        geom: int | str | None = None,
        body: int | str | None = None,
        pad: PadConfig | object | str | None = None,
        normal_axis: Sequence[float] = (0.0, 0.0, 1.0),
        up_axis: Sequence[float] = (1.0, 0.0, 0.0),
        pad_center: Sequence[float] | None = (0.0, 0.0, 0.0),
        objects: Iterable[int | str] | None = None,
        simulator: object | None = None,
        n_grid: int = 64,
        name: str | None = None,
        use_penetration: bool = False,
    ) -> None:
        if not isinstance(model, mujoco.MjModel) or not isinstance(data, mujoco.MjData):
            raise ValueError("TactileSensor needs a mujoco.MjModel and its mujoco.MjData")
        if (geom is None) == (body is None):
            raise ValueError("give exactly one of geom= (the pad's geom) or body= (the pad's body)")
        self.model, self.data = model, data
        if geom is not None:
            self.geom = _id(model, mujoco.mjtObj.mjOBJ_GEOM, geom, "geom")
            self.body = int(model.geom_bodyid[self.geom])
            self.pad_geoms = np.array([self.geom])
        else:
            self.geom = -1
            self.body = _id(model, mujoco.mjtObj.mjOBJ_BODY, body, "body")
            self.pad_geoms = np.flatnonzero(np.asarray(model.geom_bodyid) == self.body)
            if len(self.pad_geoms) == 0:
                raise ValueError(f"body {body!r} has no geoms: the pad needs a geom to collide with")
        label = name or (mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, self.geom) if self.geom >= 0 else None)
        pad_cfg = PadConfig.coerce(pad, n_grid)
        super().__init__(normal_axis, up_axis, pad_center, pad_cfg, simulator, label or "pad", use_penetration)
        self.feel = None if objects is None else {_id(model, mujoco.mjtObj.mjOBJ_GEOM, g, "geom") for g in objects}
        self._force = np.zeros(6)

    # ------------------------------------------------------------------ engine side
    def link_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """((3,) world position, (3,3) world rotation) float64 of the pad geom's (or body's) frame."""
        d = self.data
        if self.geom >= 0:
            return np.array(d.geom_xpos[self.geom]), np.array(d.geom_xmat[self.geom]).reshape(3, 3)
        return np.array(d.xpos[self.body]), np.array(d.xmat[self.body]).reshape(3, 3)

    def object_transform(self, key: int) -> np.ndarray:
        """(4,4) float64 world transform of geom ``key``'s frame."""
        T = np.eye(4)
        T[:3, :3] = np.asarray(self.data.geom_xmat[key]).reshape(3, 3)
        T[:3, 3] = self.data.geom_xpos[key]
        return T

    def object_mesh(self, key: int) -> trimesh.Trimesh:
        """Geom ``key``'s surface in its frame: an :meth:`attach_object` mesh, else :func:`geom_mesh` (cached)."""
        if key not in self.objects:
            self.objects[key] = geom_mesh(self.model, key)
        return self.objects[key]

    def contact_points(self) -> list[ContactPoint]:
        """The pad geoms' active contacts in ``data`` (MuJoCo's contact normal runs from geom1 to geom2)."""
        d = self.data
        n = int(d.ncon)
        if n == 0:
            return []
        con = d.contact
        pair = np.asarray(con.geom[:n])  # (n,2)
        on1 = np.isin(pair[:, 0], self.pad_geoms)
        on2 = np.isin(pair[:, 1], self.pad_geoms)
        hit = np.flatnonzero((on1 ^ on2) & (np.asarray(con.efc_address[:n]) >= 0))
        out = []
        for i in hit:
            other = int(pair[i, 1] if on1[i] else pair[i, 0])
            if int(self.model.geom_bodyid[other]) == self.body or (self.feel is not None and other not in self.feel):
                continue
            mujoco.mj_contactForce(self.model, d, int(i), self._force)
            normal = np.array(con.frame[i, :3], dtype=np.float64)  # geom1 -> geom2
            to_pad = -normal if on1[i] else normal  # from the object towards the pad
            pen = max(0.0, -float(con.dist[i]))
            point = np.array(con.pos[i], dtype=np.float64) + to_pad * pen / 2  # on the object's surface
            out.append(ContactPoint(other, point, to_pad, pen, max(0.0, float(self._force[0]))))
        return out
