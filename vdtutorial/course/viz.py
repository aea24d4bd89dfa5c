"""Look at the simulation from a notebook: a 3-D meshcat view of pybullet bodies, and camera frames.

Two kinds of pictures matter in this tutorial. The 3-D scene (arm, table, cup, the IK solution set
drawn as ghost arms, a rollout played back) explains *what the policy does*; the camera frames explain
*what the policy sees*. Both have to show up inside a notebook that may run on a remote JupyterHub or
headless under ``pytest --nbmake`` in CI, where no browser can reach a port on the kernel's machine.

meshcat normally runs a tornado/ZMQ server that the browser reaches over a websocket; with meshcat 0.3.2
that is fragile here (see :class:`Recorder`), so by default no server starts: the scene is recorded in
memory and :meth:`Recorder.html` replays it into one self-contained page that needs no network. Shown inline in
a notebook, only the notebook's first scene carries the viewer's JavaScript and the later ones take it from the
notebook page (:meth:`Recorder.iframe`), which keeps a saved chapter small.

Mirroring is generic: it works from pybullet body ids and ``getVisualShapeData`` alone and never
imports the environment modules, so the same code draws the arm, the table and the cup. The module
only *reads* the simulation; the one place where the state moves is :func:`record_rollout`, and there
it is the caller's ``set_state`` that moves it.

Taught in chapter 01.
"""

from __future__ import annotations

import base64
import functools
import gzip
import html
import json
import sys
import uuid
import warnings
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import pybullet as p
import umsgpack

with warnings.catch_warnings():
    # meshcat's server module imports the deprecated zmq.eventloop.ioloop at import time.
    warnings.filterwarnings("ignore", message=".*zmq.eventloop.ioloop.*", category=DeprecationWarning)
    import meshcat
    import meshcat.animation
    import meshcat.geometry as mg
    from meshcat.servers.tree import SceneTree, find_node, walk
    from meshcat.servers.zmqserver import VIEWER_ROOT
    from meshcat.visualizer import ViewerWindow

__all__ = [
    "Recorder",
    "mirror_bodies",
    "frame_view",
    "frame_points",
    "update_poses",
    "add_ghost",
    "record_rollout",
    "show_rgbd",
    "frames_animation",
    "palette_png",
    "compact_figures",
]

#: Side length (m) of the square drawn for a ``GEOM_PLANE``, which pybullet reports without a size.
PLANE_SIZE = 4.0
#: Vertical field of view (degrees) of meshcat's default perspective camera.
CAMERA_FOV_DEG = 75.0
#: Direction from the scene's centre to the camera (x, y, z; z up): in front of the arm, to its right, above.
VIEW_DIRECTION = (1.0, -1.1, 0.8)
#: Width over height of an inline scene (:meth:`Recorder.show`), for which :func:`frame_view` frames the bodies.
VIEW_ASPECT = 4 / 3
#: A visual shape wider than this (m) in some direction is the stage (the table, a ground plane): drawn, not framed.
STAGE_SIZE = 1.0
#: Passes of :func:`frame_view` that move the look-at point to the middle of the picture (3 settle it to ~1 %).
FRAMING_PASSES = 3
#: Ghost colour: light blue, mostly transparent so the real arm stays readable behind the ghosts.
GHOST_RGBA = (0.25, 0.6, 1.0, 0.3)

# three.js cylinders run along +Y, URDF/pybullet cylinders and capsules along +Z: +90 deg about X
# maps Y onto Z.
_Y_TO_Z = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])

_MESH_LOADERS = {
    ".obj": mg.ObjMeshGeometry.from_file,
    ".stl": mg.StlMeshGeometry.from_file,
    ".dae": mg.DaeMeshGeometry.from_file,
}


# --------------------------------------------------------------------------------------------------
# Server-free meshcat
# --------------------------------------------------------------------------------------------------
class _SceneTreeWindow:
    """The part of a meshcat window that ``Visualizer`` uses: ``send(command)``.

    Each command is packed with msgpack, as it would travel to the server, and stored in a
    ``SceneTree`` with the server's rules (a new object resets the node's properties, ``delete``
    drops a subtree). With ``forward`` set, the command is also passed on to a live viewer window.
    """

    def __init__(self, forward: ViewerWindow | None = None):
        self.tree = SceneTree()
        self.forward = forward

    def send(self, command) -> None:
        data = command.lower()
        path = [part for part in data["path"].split("/") if part]
        kind = data["type"]
        if kind == "delete":
            if path:
                find_node(self.tree, path[:-1]).pop(path[-1], None)
            else:
                self.tree = SceneTree()
        else:
            node = find_node(self.tree, path)
            packed = umsgpack.packb(data)
            if kind == "set_object":
                node.object = packed
                node.properties = []
            elif kind == "set_transform":
                node.transform = packed
            elif kind == "set_property":
                node.properties.append(packed)
            elif kind == "set_animation":
                node.animation = packed
            else:
                raise ValueError(f"the in-memory meshcat window cannot handle {kind!r}")
        if self.forward is not None:
            self.forward.send(command)


def _packed(data: bytes) -> str:
    """``data`` gzip-compressed and base64-encoded, for a page that inflates it with the browser's own
    ``DecompressionStream``: the viewer shrinks to about a third, a scene's meshes and poses to about half."""
    return base64.b64encode(gzip.compress(data, mtime=0)).decode("ascii")


@functools.lru_cache(maxsize=1)
def _viewer_packed() -> str:
    """The meshcat viewer bundle (three.js included), packed by :func:`_packed`, made once per process."""
    return _packed((Path(VIEWER_ROOT) / "main.min.js").read_bytes())


#: The global of the notebook page (an iframe's parent) where the first scene leaves the viewer's source for the
#: scenes after it.
_SHARED_VIEWER = "__vdtutorialMeshcatViewer"
#: A scene page's viewer, inlined; it also leaves its source on the parent page, for the scenes that come without it.
_VIEWER_INLINE = """<script>
inflate("{viewer}").then((bytes) => {{
  const source = new TextDecoder().decode(bytes);
  try {{ parent.{shared} = source; }} catch (error) {{}}
  startViewer(source);
}});
</script>"""
#: A scene page without the viewer: it takes the source the notebook's first scene left on the parent page, waiting
#: for it when that scene has not loaded yet, and says where the viewer comes from while it waits.
_VIEWER_SHARED = """<script>
const waitingSince = Date.now();
(function takeViewer() {{
  let source = null;
  try {{ source = parent.{shared} || null; }} catch (error) {{}}
  if (source === null) {{
    if (Date.now() - waitingSince > 3000) document.getElementById("waiting").hidden = false;
    setTimeout(takeViewer, 300);
    return;
  }}
  document.getElementById("waiting").remove();
  startViewer(source);
}})();
</script>"""
_PAGE = """<!DOCTYPE html>
<html>
<head><meta charset="utf-8"><title>vdtutorial scene</title>
<style>html, body {{ margin: 0; height: 100%; overflow: hidden; }} #scene {{ width: 100vw; height: 100vh; }}
#waiting {{ position: absolute; top: 1em; left: 1em; right: 1em; font: 14px sans-serif; }}</style>
</head>
<body>
<p id="waiting" hidden>This 3-D scene uses the viewer that the first scene of this notebook brings along: scroll up to
that scene (or run its cell again) and this one draws itself.</p>
<div id="scene"></div>
<script>
// Packed data (gzip, then base64) back to bytes.
async function inflate(packed) {{
  const bytes = Uint8Array.from(atob(packed), (c) => c.charCodeAt(0));
  const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream("gzip"));
  return new Uint8Array(await new Response(stream).arrayBuffer());
}}
// Run the viewer's source, then replay the recorded meshcat commands in recording order (objects, transforms,
// the animation); each is msgpack, preceded by its length (4 bytes, big-endian).
async function startViewer(source) {{
  const script = document.createElement("script");
  script.textContent = source;
  document.head.appendChild(script);
  const viewer = new MeshCat.Viewer(document.getElementById("scene"));
  const commands = await inflate("{commands}");
  const sizes = new DataView(commands.buffer);
  for (let at = 0; at < commands.length; ) {{
    const size = sizes.getUint32(at);
    viewer.handle_command_bytearray(commands.slice(at + 4, at + 4 + size));
    at += 4 + size;
  }}
  // The point the camera looks at and orbits about (frame_view), in three.js's frame (y up); null: the origin.
  const lookAt = {look_at};
  if (lookAt !== null) {{
    viewer.controls.target.set(lookAt[0], lookAt[1], lookAt[2]);
    viewer.controls.update();
  }}
}}
</script>
{viewer}
</body>
</html>
"""


#: Which display of the running kernel brought the viewer along: (the request it answered, the notebook cell that
#: sent the request or None), see :func:`_brings_viewer`.
_viewer_display: tuple[str, str | None] | None = None


def _brings_viewer() -> bool:
    """Whether the scene about to be shown inline carries the viewer's JavaScript itself.

    The viewer (three.js included) is most of a scene's page, and a notebook stores every output it shows: a
    copy per scene made a chapter of a few scenes weigh megabytes. So in a notebook kernel the first scene brings
    the viewer and leaves its source on the notebook page, and every later scene takes it from there. The scenes
    of a cell that brought it once bring it again when that cell runs again (JupyterLab names the cell in its
    request), so that re-running it keeps a copy in the saved notebook. Outside a notebook kernel, and in Colab,
    which shows each output in a page of its own, every scene brings its own viewer.
    """
    global _viewer_display
    shell = sys.modules["IPython"].get_ipython() if "IPython" in sys.modules else None
    kernel = getattr(shell, "kernel", None)
    if kernel is None or "google.colab" in sys.modules:
        return True
    parent = kernel.get_parent() or {}
    request, cell = parent.get("header", {}).get("msg_id"), (parent.get("metadata") or {}).get("cellId")
    if request is None:
        return True
    if _viewer_display is None or (cell is not None and cell == _viewer_display[1] and request != _viewer_display[0]):
        _viewer_display = (request, cell)
        return True
    return False


class Recorder:
    """A meshcat scene kept in memory and shown as a self-contained HTML page.

    ``recorder.vis`` is an ordinary ``meshcat.Visualizer`` (``vis["a/b"].set_object(...)`` etc.);
    every command is recorded instead of being sent to a server. :meth:`show` (or just ending a
    notebook cell with the recorder) draws the scene inline; :meth:`save` writes the page to disk.
    The viewer's own nodes can be changed as usual, e.g. ``vis["/Grid"].set_property("visible", False)``.

    ``live=True`` additionally starts meshcat's usual server subprocess and forwards every command to
    it, for an interactive view that follows the simulation (:attr:`url`). Use it only where the
    browser can reach the kernel's ports. meshcat's ``Visualizer.close()`` is broken in 0.3.2
    (``AttributeError``), and after the server dies the next command blocks forever; call
    :meth:`close` here instead, which stops the server and keeps recording in memory.

    Why no server by default: meshcat normally runs a tornado/ZMQ server in a subprocess. With
    meshcat 0.3.2 that is fragile here: ``Visualizer.close()`` raises ``AttributeError`` (its window has
    no ``close``) and once the server process is gone every further call blocks forever on the ZMQ reply.
    So the recorder hands ``meshcat.Visualizer`` a window object whose ``send`` stores each command in an
    in-memory ``SceneTree``, exactly the bookkeeping the meshcat server does, and replays that tree into a
    page with the viewer's JavaScript inlined, which renders in an ``<iframe srcdoc=...>`` anywhere.
    """

    def __init__(self, live: bool = False):
        forward = ViewerWindow(zmq_url=None, start_server=True, server_args=[]) if live else None
        self._window = _SceneTreeWindow(forward)
        self.vis = meshcat.Visualizer(window=self._window)
        #: The point (world frame, z up) the page's camera looks at and orbits about, set by
        #: :func:`frame_view`; None: the world origin, as in meshcat's own viewer.
        self.look_at: np.ndarray | None = None

    @property
    def tree(self) -> SceneTree:
        """The recorded scene: meshcat's ``SceneTree`` of msgpack-packed commands."""
        return self._window.tree

    @property
    def url(self) -> str:
        """Address of the live viewer (only with ``live=True``)."""
        if self._window.forward is None:
            raise RuntimeError("this Recorder has no live server; create it with live=True")
        return self._window.forward.web_url

    def close(self) -> None:
        """Stop the live server subprocess (if any); recording and :meth:`html` keep working."""
        forward, self._window.forward = self._window.forward, None
        if forward is not None:
            forward.server_proc.kill()
            forward.server_proc.wait()

    def html(self, viewer: bool = True) -> str:
        """The standalone page: viewer JavaScript plus every recorded command, no network access. With ``viewer``
        False the page has no viewer of its own and takes the one an earlier scene left on the notebook page."""
        commands = b""
        for node in walk(self.tree):
            for packed in (node.object, *node.properties, node.transform, node.animation):
                if packed is not None:
                    commands += len(packed).to_bytes(4, "big") + packed
        look_at = None if self.look_at is None else _three_frame(self.look_at)
        script = (
            _VIEWER_INLINE.format(viewer=_viewer_packed(), shared=_SHARED_VIEWER)
            if viewer
            else _VIEWER_SHARED.format(shared=_SHARED_VIEWER)
        )
        return _PAGE.format(viewer=script, commands=_packed(commands), look_at=json.dumps(look_at))

    def iframe(self, style: str = "width: 100%; height: 100%; border: none;") -> str:
        """The scene as an ``<iframe srcdoc=...>`` element for a notebook's HTML output; in a notebook kernel only
        the first scene carries the viewer (:func:`_brings_viewer`)."""
        page = html.escape(self.html(viewer=_brings_viewer()), quote=True)
        return f'<iframe srcdoc="{page}" style="{style}"></iframe>'

    def _iframe(self, height: int) -> str:
        # srcdoc carries the whole page, so Jupyter needs no server or file to display it. The wrapping div
        # has the shape frame_view frames the scene for (VIEW_ASPECT), at most ``height`` pixels high and
        # narrower on a narrow screen; the reader can drag it larger.
        width = int(round(height * VIEW_ASPECT))
        return (
            f'<div style="width: 100%; max-width: {width}px; aspect-ratio: {width} / {int(height)}; '
            f'resize: both; overflow: hidden;">{self.iframe()}</div>'
        )

    def show(self, height: int = 400):
        """An IPython display object drawing the scene inline (an ``<iframe srcdoc=...>``), ``height`` pixels
        high at most and :data:`VIEW_ASPECT` times as wide."""
        from IPython.display import HTML

        return HTML(self._iframe(height))

    def _repr_html_(self) -> str:
        return self._iframe(400)

    def save(self, path: str | Path) -> Path:
        """Write :meth:`html` to ``path`` and return it; the file opens in any browser, offline."""
        path = Path(path)
        path.write_text(self.html(), encoding="utf-8")
        return path


def _visualizer(target) -> Any:
    """Accept a :class:`Recorder` wherever a meshcat visualizer is expected."""
    return target.vis if isinstance(target, Recorder) else target


# --------------------------------------------------------------------------------------------------
# Mirroring pybullet bodies
# --------------------------------------------------------------------------------------------------
def _pose_matrix(position, quaternion) -> np.ndarray:
    """4x4 homogeneous transform from a pybullet position and (x, y, z, w) quaternion."""
    matrix = np.eye(4)
    matrix[:3, :3] = np.reshape(p.getMatrixFromQuaternion(quaternion), (3, 3))
    matrix[:3, 3] = position
    return matrix


def _link_frames(client_id: int, body: int) -> dict[int, np.ndarray]:
    """World poses of the URDF link frames of ``body``, keyed by link index (-1 is the base).

    Visual frames hang off these frames, not off the centres of mass. pybullet keeps the base at its
    inertial frame, so the base link frame is recovered through the local inertial frame.
    """
    position, orientation = p.getBasePositionAndOrientation(body, physicsClientId=client_id)
    inertial_position, inertial_orientation = p.getDynamicsInfo(body, -1, physicsClientId=client_id)[3:5]
    frames = {
        -1: _pose_matrix(position, orientation) @ np.linalg.inv(_pose_matrix(inertial_position, inertial_orientation))
    }
    n_links = p.getNumJoints(body, physicsClientId=client_id)
    if n_links:
        # computeForwardKinematics: frames follow resetJointState without a stepSimulation.
        states = p.getLinkStates(body, list(range(n_links)), computeForwardKinematics=True, physicsClientId=client_id)
        for link, state in enumerate(states):
            frames[link] = _pose_matrix(state[4], state[5])
    return frames


def _link_names(client_id: int, body: int) -> dict[int, str]:
    """meshcat node names for the links: the URDF names, made path-safe and unique."""
    raw = {-1: p.getBodyInfo(body, physicsClientId=client_id)[0]}
    for link in range(p.getNumJoints(body, physicsClientId=client_id)):
        raw[link] = p.getJointInfo(body, link, physicsClientId=client_id)[12]
    names: dict[int, str] = {}
    for link, name in raw.items():
        name = name.decode("utf-8").replace("/", "_")
        if not name or name in names.values():
            name = "base" if link == -1 else f"link{link}"
        names[link] = name
    return names


def _material(rgba) -> mg.MeshPhongMaterial:
    """A meshcat material from a pybullet rgba; alpha below 1 makes it transparent."""
    red, green, blue = (int(round(255 * float(np.clip(c, 0.0, 1.0)))) for c in rgba[:3])
    return mg.MeshPhongMaterial(color=(red << 16) | (green << 8) | blue, opacity=float(rgba[3]))


def _set_shape(node, geom_type: int, dims, mesh_file: str, material) -> None:
    """Draw one pybullet visual shape under ``node``, whose frame is the shape's visual frame.

    Shape-specific corrections (cylinder axis, capsule caps, mesh scale) live in child nodes with
    fixed transforms, so the animated link nodes above only ever carry rigid link poses.
    """
    if geom_type == p.GEOM_BOX:
        node["box"].set_object(mg.Box(list(dims[:3])), material)
    elif geom_type == p.GEOM_SPHERE:
        node["sphere"].set_object(mg.Sphere(dims[0]), material)
    elif geom_type in (p.GEOM_CYLINDER, p.GEOM_CAPSULE):
        length, radius = dims[0], dims[1]
        node["cylinder"].set_object(mg.Cylinder(length, radius), material)
        node["cylinder"].set_transform(_Y_TO_Z)
        if geom_type == p.GEOM_CAPSULE:  # meshcat has no capsule: add the two half-sphere ends
            for cap, z in (("cap_top", 0.5 * length), ("cap_bottom", -0.5 * length)):
                node[cap].set_object(mg.Sphere(radius), material)
                node[cap].set_transform(_pose_matrix((0.0, 0.0, z), (0.0, 0.0, 0.0, 1.0)))
    elif geom_type == p.GEOM_MESH:
        loader = _MESH_LOADERS.get(Path(mesh_file).suffix.lower())
        if loader is None or not Path(mesh_file).is_file():
            warnings.warn(f"skipping a mesh visual meshcat cannot load: {mesh_file or '(no file)'!r}", stacklevel=3)
            return
        node["mesh"].set_object(loader(mesh_file), material)
        node["mesh"].set_transform(np.diag([*dims[:3], 1.0]))  # pybullet reports the mesh scale
    elif geom_type == p.GEOM_PLANE:
        # An infinite plane through the visual frame with normal +z: draw a thin square whose top
        # face lies in the plane.
        thickness = 1e-3
        node["plane"].set_object(mg.Box([PLANE_SIZE, PLANE_SIZE, thickness]), material)
        node["plane"].set_transform(_pose_matrix((0.0, 0.0, -0.5 * thickness), (0.0, 0.0, 0.0, 1.0)))
    else:
        warnings.warn(f"skipping a visual of unknown pybullet geometry type {geom_type}", stacklevel=3)


def _mirror_body(node, client_id: int, body: int, rgba=None) -> None:
    """Create meshcat geometry for every visual of ``body`` under ``node`` (replacing old content).

    Layout: ``node/<link name>`` carries the link's world pose, ``node/<link name>/visual<k>`` the
    k-th visual's local frame within that link. Link names are pybullet's: the URDF names, and
    ``link0`` for the base of a ``createMultiBody`` body. ``rgba`` overrides the colours (ghosts).
    """
    node.delete()
    names = _link_names(client_id, body)
    counts: dict[int, int] = {}
    for shape in p.getVisualShapeData(body, physicsClientId=client_id):
        link, geom_type, dims, mesh_file, position, orientation, colour = shape[1:8]
        k = counts[link] = counts.get(link, -1) + 1
        visual = node[names[link]][f"visual{k}"]
        visual.set_transform(_pose_matrix(position, orientation))
        _set_shape(visual, geom_type, dims, mesh_file.decode("utf-8"), _material(rgba or colour))


def _scene_poses(client_id: int, bodies: Mapping[str, int]) -> dict[tuple[str, str], np.ndarray]:
    """World pose of every link that has a visual, keyed by (body name, link name)."""
    poses = {}
    for name, body in bodies.items():
        frames = _link_frames(client_id, body)
        link_names = _link_names(client_id, body)
        for link in sorted({shape[1] for shape in p.getVisualShapeData(body, physicsClientId=client_id)}):
            poses[(name, link_names[link])] = frames[link]
    return poses


def update_poses(vis, client_id: int, bodies: Mapping[str, int]) -> None:
    """Move the mirrored links to the bodies' current poses in the simulation.

    ``vis`` is a :class:`Recorder`, a meshcat visualizer, or an animation frame
    (``animation.at_frame(vis, i)``), which has the same ``[path].set_transform`` interface.
    """
    vis = _visualizer(vis)
    for (body_name, link_name), pose in _scene_poses(client_id, bodies).items():
        vis[body_name][link_name].set_transform(pose)


def mirror_bodies(vis, client_id: int, bodies: Mapping[str, int]) -> None:
    """Draw pybullet bodies in meshcat at their current poses, one node per name in ``bodies``.

    Geometry is built from ``getVisualShapeData`` (boxes, spheres, cylinders, capsules, planes,
    .obj/.stl/.dae meshes; other meshes are skipped with a warning), so it works for any body: a
    URDF robot or a ``createMultiBody`` table or cup. Call it once, then :func:`update_poses` as
    the simulation moves.

    Conventions checked numerically against pybullet 3.2.7 (see ``tests/test_viz.py``):

    * ``getVisualShapeData`` dimensions are the *full* box extents (twice ``halfExtents``);
      ``(length, radius, 0)`` for cylinders and capsules, where a capsule's ``length`` is its cylindrical
      part only (the half-spheres add ``radius`` at each end); ``(radius, 0, 0)`` for spheres; the mesh
      scale for meshes.
    * The local visual frame is relative to the URDF link frame, for the base too. Link frames are
      ``getLinkState(...)[4:6]``; ``[0:2]`` is the centre of mass. ``getBasePositionAndOrientation``
      returns the base's *inertial* frame, so the base link frame is that pose times the inverse of the
      local inertial frame from ``getDynamicsInfo(body, -1)[3:5]``.
    """
    for name, body in bodies.items():
        _mirror_body(_visualizer(vis)[name], client_id, body)
    update_poses(vis, client_id, bodies)
    frame_view(vis, client_id, bodies)


def _view_basis(direction: Sequence[float]) -> np.ndarray:
    """Rows: the camera's right, up and forward axes (world frame, z up) when it looks along ``-direction``."""
    forward = -np.asarray(direction, dtype=float) / np.linalg.norm(direction)
    right = np.cross(forward, (0.0, 0.0, 1.0))
    right /= np.linalg.norm(right)
    return np.array([right, np.cross(right, forward), forward])


def _fitting_distance(points: np.ndarray, basis: np.ndarray, tan_limit: np.ndarray) -> float:
    """The smallest distance (1 cm steps) from which a camera on the ray ``-basis[2]`` from the origin, looking
    at the origin, sees every point within ``tan_limit`` (tangents of the half-angles: horizontal, vertical)."""
    for distance in np.arange(0.3, 10.0, 0.01):
        right, up, depth = basis @ (points + distance * basis[2]).T
        if np.all(depth > 0) and np.all(np.abs(np.stack([right, up])) / depth <= tan_limit[:, None]):
            return float(distance)
    raise ValueError("the bodies are too large to frame from 10 m")


def _visual_half_extents(geom_type: int, dims) -> np.ndarray | None:
    """Half extents of a visual shape's box in its own frame (pybullet's conventions above); None for a mesh
    or a plane, whose size ``getVisualShapeData`` does not give."""
    if geom_type == p.GEOM_BOX:
        return np.asarray(dims[:3], dtype=float) / 2
    if geom_type == p.GEOM_SPHERE:
        return np.full(3, float(dims[0]))
    if geom_type in (p.GEOM_CYLINDER, p.GEOM_CAPSULE):
        length, radius = float(dims[0]), float(dims[1])
        return np.array([radius, radius, length / 2 + (radius if geom_type == p.GEOM_CAPSULE else 0.0)])
    return None


def subject_corners(client_id: int, bodies: Mapping[str, int]) -> np.ndarray:
    """The corners of the boxes around the bodies' visual shapes that a view should frame (n x 3, world
    frame): those of the subject (the arm, the cup), not of the stage (a shape wider than
    :data:`STAGE_SIZE`: the table, a ground plane), unless the stage is all there is. A mesh or a plane
    counts with its link's bounding box (pybullet's, from the collision shapes)."""
    signs = np.array(list(np.ndindex(2, 2, 2))) * 2 - 1
    subject, stage = [], []
    for body in bodies.values():
        frames = _link_frames(client_id, body)
        for shape in p.getVisualShapeData(body, physicsClientId=client_id):
            link, geom_type, dims, _, position, orientation = shape[1:7]
            half = _visual_half_extents(geom_type, dims)
            if half is None:
                low, high = np.array(p.getAABB(body, link, physicsClientId=client_id))
                corners, size = (low + high) / 2 + signs * (high - low) / 2, np.max(high - low)
            else:
                pose = frames[link] @ _pose_matrix(position, orientation)
                corners, size = (signs * half) @ pose[:3, :3].T + pose[:3, 3], 2 * np.max(half)
            (stage if size > STAGE_SIZE else subject).extend(corners)
    return np.array(subject or stage)


def frame_view(
    vis,
    client_id: int,
    bodies: Mapping[str, int],
    margin: float = 1.1,
    direction: Sequence[float] = VIEW_DIRECTION,
    aspect: float = VIEW_ASPECT,
) -> np.ndarray:
    """Aim meshcat's default camera at the bodies and move it so that the arm and the cup fill the view;
    returns the camera position (world frame). See :func:`frame_points`."""
    return frame_points(vis, subject_corners(client_id, bodies), margin, direction, aspect)


def frame_points(
    vis,
    points: np.ndarray,
    margin: float = 1.1,
    direction: Sequence[float] = VIEW_DIRECTION,
    aspect: float = VIEW_ASPECT,
) -> np.ndarray:
    """Aim meshcat's default camera so that ``points`` (n x 3, world frame) fill the view; returns the camera
    position (world frame).

    meshcat's camera starts 3 m from the origin and looks at it, where the arm fills 10-15 % of the frame.
    Here the camera looks along ``-direction`` (from in front of the arm, to its right, above) at the middle
    of the points' picture, from the smallest distance at which every point lies within the vertical field
    of view and, for a view ``aspect`` times as wide as it is high (:meth:`Recorder.show` draws that shape),
    the horizontal one, each shrunk by ``margin``. The camera's position is a property of
    ``/Cameras/default/rotated/<object>``; meshcat 0.3.2 has no command for the point it looks at, so that
    point is kept in a :class:`Recorder` (:attr:`Recorder.look_at`), whose page aims the viewer's orbit
    controls at it. A plain meshcat visualizer gets the position only and keeps looking at the origin.
    """
    points = np.asarray(points, dtype=float)
    basis = _view_basis(direction)
    tan_limit = np.tan(np.radians(CAMERA_FOV_DEG / 2)) / margin * np.array([aspect, 1.0])
    offset = -basis[2]  # unit vector from the look-at point towards the camera
    centre = (points.min(0) + points.max(0)) / 2
    for _ in range(FRAMING_PASSES):
        distance = _fitting_distance(points - centre, basis, tan_limit)
        # Perspective draws the near points larger: the box's centre is not the middle of its picture. Move
        # the look-at point (and the camera with it) across the view to the middle of the picture, then refit.
        right, up, depth = basis @ (points - (centre + distance * offset)).T
        middle = [(np.max(ratio) + np.min(ratio)) / 2 for ratio in (right / depth, up / depth)]
        centre = centre + distance * (middle[0] * basis[0] + middle[1] * basis[1])
    camera = centre + _fitting_distance(points - centre, basis, tan_limit) * offset
    if isinstance(vis, Recorder):
        vis.look_at = centre
    _visualizer(vis)["/Cameras/default/rotated/<object>"].set_property("position", _three_frame(camera))
    return camera


def _three_frame(point) -> list[float]:
    """A world point (z up) in three.js's frame (y up), the frame of meshcat's camera: (x, y, z) -> (x, z, -y)."""
    return [float(point[0]), float(point[2]), -float(point[1])]


def add_ghost(vis, client_id: int, body: int, name: str, rgba: Sequence[float] = GHOST_RGBA) -> None:
    """Freeze a translucent copy of ``body``, as it is posed right now, under the node ``name``.

    Used to draw a set of arm configurations at once (e.g. the IK solutions reaching a cup): put the
    arm in each configuration, call ``add_ghost`` with a new name, then restore the arm. Ghosts are
    static; :func:`update_poses` and :func:`record_rollout` only move the bodies they are given.
    """
    vis = _visualizer(vis)
    _mirror_body(vis[name], client_id, body, rgba=tuple(rgba))
    update_poses(vis, client_id, {name: body})


def record_rollout(
    client_id: int,
    bodies: Mapping[str, int],
    states: Sequence,
    set_state: Callable[[Any], None],
    fps: float = 10,
    repetitions: int = 1,
    recorder: Recorder | None = None,
) -> Recorder:
    """Turn a rollout into a meshcat animation that plays inline.

    ``set_state(state)`` must put the simulation into each recorded state (e.g. reset the joint
    angles); the simulation is left in the last state. The scene starts at the first state, and
    only links that move get an animation track, which keeps the page small. Pass ``recorder`` to
    add the animation to an existing scene (e.g. one with ghosts). Returns the recorder; end a cell
    with it, or call ``.show()``.
    """
    states = list(states)
    if not states:
        raise ValueError("record_rollout needs at least one state")
    recorder = Recorder() if recorder is None else recorder
    set_state(states[0])
    mirror_bodies(recorder, client_id, bodies)
    frames, corners = [], []
    for state in states:
        set_state(state)
        frames.append(_scene_poses(client_id, bodies))
        corners.append(subject_corners(client_id, bodies))
    frame_points(recorder, np.concatenate(corners))  # the whole motion in view, not only its first state

    animation = meshcat.animation.Animation(default_framerate=fps)
    for key in frames[0]:
        track = [poses[key] for poses in frames]
        if all(np.allclose(pose, track[0]) for pose in track):
            continue  # static link: the transform set by mirror_bodies already holds
        for index, pose in enumerate(track):
            with animation.at_frame(recorder.vis, index) as frame:
                frame[key[0]][key[1]].set_transform(pose)
    if animation.clips:
        recorder.vis.set_animation(animation, play=True, repetitions=repetitions)
    return recorder


# --------------------------------------------------------------------------------------------------
# Camera frames
# --------------------------------------------------------------------------------------------------
def _as_rgb(image) -> np.ndarray:
    """RGB for imshow: drops an alpha channel (pybullet returns RGBA) and maps 0..255 floats to 0..1."""
    image = np.asarray(image)[..., :3]
    if np.issubdtype(image.dtype, np.floating):
        image = np.clip(image / 255.0 if image.max() > 1.0 else image, 0.0, 1.0)
    return image


def show_rgbd(rgbd, title: str | None = None):
    """A figure with the RGB image and the depth map (metres, with a colour bar) side by side.

    ``rgbd`` is either a pair ``(rgb, depth)`` or one ``H x W x 4`` array whose last channel is the
    depth. Depth must already be metric, not pybullet's non-linear z-buffer. The figure is closed in
    pyplot before it is returned, so it shows exactly once when it ends a notebook cell.
    """
    import matplotlib.pyplot as plt

    if isinstance(rgbd, (tuple, list)):
        rgb, depth = rgbd
    else:
        rgbd = np.asarray(rgbd)
        rgb, depth = rgbd[..., :3], rgbd[..., 3]
    fig, (ax_rgb, ax_depth) = plt.subplots(1, 2, figsize=(8.0, 3.4), layout="constrained")
    ax_rgb.imshow(_as_rgb(rgb))
    ax_rgb.set_title("RGB")
    shown = ax_depth.imshow(np.asarray(depth, dtype=float), cmap="viridis")
    ax_depth.set_title("depth")
    fig.colorbar(shown, ax=ax_depth, label="depth [m]")
    for ax in (ax_rgb, ax_depth):
        ax.set_axis_off()
    if title:
        fig.suptitle(title)
    plt.close(fig)
    return fig


#: The frame player's page: one ``<img>`` sized in pixels (a notebook front end's ``max-width: 100%; height: auto``
#: on images inside a shrink-to-fit box lays an image without a size out at 0 x 0), a play/pause button, a range
#: input and a frame counter, all drawn by the browser: no script, style sheet or font from another host.
_PLAYER = """<div id="{id}" class="vdtutorial-frames" style="display: block;">
<img src="{first}" alt="camera frame 1 of {count}" width="{width}" height="{height}"
 style="display: block; width: {width}px; height: {height}px; max-width: none; image-rendering: pixelated;">
<div style="display: flex; align-items: center; gap: 8px; margin-top: 4px; width: {width}px; max-width: none;">
<button type="button" style="min-width: 5em;">play</button>
<input type="range" min="0" max="{last}" value="0" step="1" style="flex: 1;" aria-label="frame">
<span style="font-family: monospace;">1 / {count}</span>
</div>
<script>
(() => {{
  const root = document.getElementById("{id}");
  if (root === null || root.dataset.ready) return;
  root.dataset.ready = "1";
  const frames = {frames};
  const image = root.querySelector("img"), button = root.querySelector("button");
  const range = root.querySelector("input"), counter = root.querySelector("span");
  let timer = null;
  const show = (k) => {{
    range.value = k;
    image.src = frames[k];
    image.alt = `camera frame ${{k + 1}} of ${{frames.length}}`;
    counter.textContent = `${{k + 1}} / ${{frames.length}}`;
  }};
  const stop = () => {{ clearInterval(timer); timer = null; button.textContent = "play"; }};
  range.addEventListener("input", () => {{ stop(); show(Number(range.value)); }});
  button.addEventListener("click", () => {{
    if (timer !== null) {{ stop(); return; }}
    button.textContent = "pause";
    timer = setInterval(() => show((Number(range.value) + 1) % frames.length), {interval});
  }});
}})();
</script>
</div>
"""


def _png_data_url(frame: np.ndarray) -> str:
    """A camera frame as a ``data:`` URL of a PNG, so the page needs no file beside it."""
    import io

    from PIL import Image

    pixels = np.asarray(frame)
    if np.issubdtype(pixels.dtype, np.floating):
        pixels = np.round(pixels * 255)
    buffer = io.BytesIO()
    Image.fromarray(pixels.astype(np.uint8)).save(buffer, format="png", optimize=True)
    return "data:image/png;base64," + base64.b64encode(buffer.getvalue()).decode("ascii")


def palette_png(figure, dpi: float | None = None) -> bytes:
    """``figure`` as the notebook's inline backend draws it (cropped to what it draws, at ``dpi`` or the figure's
    own), in a PNG of at most 256 colours: a line plot or a histogram needs no more, and the file is much smaller
    than the full-colour one."""
    import io

    from IPython.core.pylabtools import print_figure
    from PIL import Image

    with Image.open(io.BytesIO(print_figure(figure, "png", bbox_inches="tight", dpi=dpi or figure.dpi))) as image:
        buffer = io.BytesIO()
        image.convert("RGB").quantize(colors=256).save(buffer, format="png", optimize=True)
    return buffer.getvalue()


def compact_figures() -> None:
    """Show every matplotlib figure of this notebook as a 256-colour PNG (:func:`palette_png`).

    A chapter stores each figure it shows; a chapter with many figures then weighs what a student hands in and a
    teacher collects. Outside IPython it does nothing."""
    import matplotlib
    from matplotlib import pyplot
    from matplotlib.figure import Figure

    shell = sys.modules["IPython"].get_ipython() if "IPython" in sys.modules else None
    if shell is not None:
        # The inline backend sets its own PNG formatter when it loads, which pyplot otherwise does at the first
        # figure: load it now, then replace its formatter.
        pyplot.switch_backend(matplotlib.get_backend())
        shell.display_formatter.formatters["image/png"].for_type(Figure, palette_png)


def frames_animation(rgb_frames: Sequence, fps: float = 10, scale: int = 1):
    """An inline player flipping through camera frames: an IPython ``HTML`` object (end a cell with it).

    The frames are stored as PNGs in the page and shown ``scale`` times their pixel size, with a play button and
    a slider. The player is written here rather than taken from matplotlib's ``to_jshtml``: that page asks a CDN
    for its buttons' icon font and leaves its image's size to the front end, which JupyterLab lays out at 0 x 0.
    """
    from IPython.display import HTML

    frames = [_as_rgb(frame) for frame in rgb_frames]
    if not frames:
        raise ValueError("frames_animation needs at least one frame")
    if fps <= 0 or int(scale) < 1:
        raise ValueError(f"frames_animation needs fps > 0 and a whole scale >= 1, not fps={fps}, scale={scale}")
    height, width = frames[0].shape[:2]
    urls = [_png_data_url(frame) for frame in frames]
    return HTML(
        _PLAYER.format(
            id=f"vdtutorial-frames-{uuid.uuid4().hex}",
            first=urls[0],
            frames=json.dumps(urls),
            count=len(urls),
            last=len(urls) - 1,
            width=width * int(scale),
            height=height * int(scale),
            interval=round(1000 / fps),
        )
    )
