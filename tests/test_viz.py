"""Tests for vdtutorial.course.viz: the server-free meshcat page, pose mirroring, and the matplotlib helpers.

The pose checks compute each visual's world pose a second way, through pybullet's own transform
helpers (and, where possible, through the collision shapes or the AABB), and compare it with the
transforms composed from the recorded meshcat scene tree.
"""

import base64
import gzip
import html
import io
import json
import re
import subprocess
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import numpy as np
import pybullet as p
import pytest
import umsgpack

import vdtutorial
from vdtutorial.course import viz
from meshcat.servers.zmqserver import VIEWER_ROOT

JACO_URDF = Path(vdtutorial.__file__).resolve().parent / "assets" / "jaco6.urdf"  # the package under test
TABLE_HALF_EXTENTS = (0.4, 0.6, 0.02)
CUP_RADIUS, CUP_LENGTH = 0.04, 0.1


@pytest.fixture(scope="module")
def scene():
    """A DIRECT client with the arm, a box table and a cylinder cup; yields (client, bodies)."""
    cid = p.connect(p.DIRECT)
    arm = p.loadURDF(str(JACO_URDF), useFixedBase=True, physicsClientId=cid)
    table_shape = p.createVisualShape(
        p.GEOM_BOX, halfExtents=TABLE_HALF_EXTENTS, rgbaColor=(0.6, 0.45, 0.3, 1.0), physicsClientId=cid
    )
    table = p.createMultiBody(0, -1, table_shape, basePosition=(0.6, 0.0, -0.02), physicsClientId=cid)
    cup_shape = p.createVisualShape(
        p.GEOM_CYLINDER, radius=CUP_RADIUS, length=CUP_LENGTH, rgbaColor=(0.8, 0.2, 0.2, 1.0), physicsClientId=cid
    )
    cup = p.createMultiBody(
        0,
        -1,
        cup_shape,
        basePosition=(0.5, 0.2, CUP_LENGTH / 2),
        baseOrientation=p.getQuaternionFromEuler((0.1, -0.2, 0.3)),
        physicsClientId=cid,
    )
    yield cid, {"arm": arm, "table": table, "cup": cup}
    p.disconnect(cid)


def set_arm(cid, arm, q):
    for joint, angle in enumerate(q):
        p.resetJointState(arm, joint, angle, physicsClientId=cid)


def random_config(cid, arm, rng):
    limits = [p.getJointInfo(arm, j, physicsClientId=cid)[8:10] for j in range(6)]
    return np.array([rng.uniform(low, high) for low, high in limits])


def node(tree, path):
    """The tree node at ``path``; fails instead of letting the defaultdict create it."""
    current = tree
    for part in path.strip("/").split("/"):
        assert part in current, f"{path} is not in the scene"
        current = current[part]
    return current


def world_transform(tree, path):
    """Compose the recorded set_transform matrices from the root down to ``path``."""
    matrix, current = np.eye(4), tree
    for part in path.strip("/").split("/"):
        assert part in current, f"{path} is not in the scene"
        current = current[part]
        if current.transform is not None:
            # meshcat sends matrices column-major
            matrix = matrix @ np.reshape(umsgpack.unpackb(current.transform)["matrix"], (4, 4)).T
    return matrix


def geometry(tree, path):
    return umsgpack.unpackb(node(tree, path).object)["object"]["geometries"][0]


def material(tree, path):
    return umsgpack.unpackb(node(tree, path).object)["object"]["materials"][0]


def pybullet_visual_poses(cid, body):
    """World (position, rotation matrix) of every visual, via pybullet's link states and multiplyTransforms."""
    poses, counts = {}, {}
    for shape in p.getVisualShapeData(body, physicsClientId=cid):
        link, local_pos, local_orn = shape[1], shape[5], shape[6]
        if link == -1:
            frame = p.getBasePositionAndOrientation(body, physicsClientId=cid)
        else:
            frame = p.getLinkState(body, link, computeForwardKinematics=True, physicsClientId=cid)[4:6]
        pos, orn = p.multiplyTransforms(frame[0], frame[1], local_pos, local_orn)
        k = counts[link] = counts.get(link, -1) + 1
        poses[(link, k)] = (np.array(pos), np.reshape(p.getMatrixFromQuaternion(orn), (3, 3)), shape[2])
    return poses


def link_name(cid, body, link):
    raw = (
        p.getBodyInfo(body, physicsClientId=cid)[0]
        if link == -1
        else p.getJointInfo(body, link, physicsClientId=cid)[12]
    )
    return raw.decode()


def _unpacked(packed: str) -> bytes:
    return gzip.decompress(base64.b64decode(packed))


def recorded_commands(page):
    """Decode the commands packed into a page back into meshcat command dicts, in their order."""
    data = _unpacked(re.search(r'await inflate\("([^"]*)"\)', page).group(1))
    commands, at = [], 0
    while at < len(data):
        size = int.from_bytes(data[at : at + 4], "big")
        commands.append(umsgpack.unpackb(data[at + 4 : at + 4 + size]))
        at += 4 + size
    return commands


def packed_viewer(page) -> str | None:
    """The viewer's source a page carries, or None."""
    match = re.search(r'^inflate\("([^"]*)"\)', page, re.MULTILINE)
    return None if match is None else _unpacked(match.group(1)).decode()


def test_page_is_self_contained_and_holds_the_scene(scene):
    cid, bodies = scene
    rec = viz.Recorder()
    viz.mirror_bodies(rec, cid, bodies)
    page = rec.html()
    assert packed_viewer(page) == (Path(VIEWER_ROOT) / "main.min.js").read_text()  # the viewer bundle, packed
    assert not re.search(r"<script[^>]*\bsrc\s*=", page)
    assert not re.search(r"<link[^>]*\bhref\s*=", page)
    assert 0.2e6 < len(page) < 0.4e6
    objects = {c["path"] for c in recorded_commands(page) if c["type"] == "set_object"}
    assert "/meshcat/table/link0/visual0/box" in objects
    assert "/meshcat/cup/link0/visual0/cylinder" in objects
    assert "/meshcat/arm/link2/visual0/cylinder" in objects
    assert "/meshcat/arm/hand/visual3/box" in objects


class _Kernel:
    """What ``Recorder.iframe`` reads of ipykernel's kernel: the request being answered."""

    def __init__(self):
        self.parent = {}

    def answer(self, request, cell=None):
        self.parent = {"header": {"msg_id": request}, "metadata": {"cellId": cell} if cell else {}}

    def get_parent(self):
        return self.parent


def test_in_a_notebook_kernel_only_the_first_scene_carries_the_viewer(scene, monkeypatch):
    """A notebook stores every scene it shows; the viewer (most of a page) goes into the first scene's output only,
    and later scenes take it from the page. A cell that carried it carries it again when it runs again, and
    outside a kernel (or in Colab, one page per output) every scene carries its own."""
    import IPython

    cid, bodies = scene
    rec = viz.Recorder()
    viz.mirror_bodies(rec, cid, bodies)

    def carries():
        return packed_viewer(html.unescape(rec.iframe())) is not None

    assert carries() and carries(), "outside a kernel every scene carries the viewer"

    kernel = _Kernel()
    monkeypatch.setattr(IPython, "get_ipython", lambda: type("Shell", (), {"kernel": kernel})())
    monkeypatch.setattr(viz, "_viewer_display", None)
    kernel.answer("run-1", cell="cell-a")
    first, second_in_same_run = rec.iframe(), rec.iframe()
    assert packed_viewer(html.unescape(first)) and packed_viewer(html.unescape(second_in_same_run)) is None
    assert len(second_in_same_run) < 0.1 * len(first)
    kernel.answer("run-2", cell="cell-b")
    assert not carries()
    kernel.answer("run-3", cell="cell-a")
    assert carries(), "the cell that carried the viewer carries it again when it runs again"
    kernel.answer("run-4")  # a front end that names no cell (nbclient)
    assert not carries()
    monkeypatch.setitem(sys.modules, "google.colab", type(sys)("google.colab"))
    assert carries()

    shared = html.unescape(re.search(r'srcdoc="([^"]*)"', second_in_same_run).group(1))
    assert not re.search(r"<script[^>]*\bsrc\s*=", shared) and "parent.__vdtutorialMeshcatViewer" in shared
    assert recorded_commands(shared) == recorded_commands(rec.html())


def test_shape_dimensions_follow_pybullet_conventions(scene):
    cid, bodies = scene
    capsule = p.createMultiBody(
        0, -1, p.createVisualShape(p.GEOM_CAPSULE, radius=0.05, length=0.3, physicsClientId=cid), physicsClientId=cid
    )
    rec = viz.Recorder()
    viz.mirror_bodies(rec, cid, {**bodies, "capsule": capsule})
    p.removeBody(capsule, physicsClientId=cid)
    box = geometry(rec.tree, "meshcat/table/link0/visual0/box")
    assert [box["width"], box["height"], box["depth"]] == pytest.approx([2 * h for h in TABLE_HALF_EXTENTS])
    cup = geometry(rec.tree, "meshcat/cup/link0/visual0/cylinder")
    assert (cup["height"], cup["radiusTop"]) == pytest.approx((CUP_LENGTH, CUP_RADIUS))
    # capsule length is the cylindrical part; the caps sit at its ends
    assert geometry(rec.tree, "meshcat/capsule/link0/visual0/cylinder")["height"] == pytest.approx(0.3)
    assert geometry(rec.tree, "meshcat/capsule/link0/visual0/cap_top")["radius"] == pytest.approx(0.05)
    top = world_transform(rec.tree, "meshcat/capsule/link0/visual0/cap_top")
    bottom = world_transform(rec.tree, "meshcat/capsule/link0/visual0/cap_bottom")
    assert top[:3, 3] == pytest.approx([0, 0, 0.15])
    assert bottom[:3, 3] == pytest.approx([0, 0, -0.15])
    assert material(rec.tree, "meshcat/table/link0/visual0/box")["color"] == (153 << 16) | (115 << 8) | 77


def test_mirrored_transforms_match_pybullet_world_poses(scene):
    cid, bodies = scene
    arm = bodies["arm"]
    rng = np.random.default_rng(7)
    rec = viz.Recorder()
    viz.mirror_bodies(rec, cid, bodies)
    for _ in range(3):
        set_arm(cid, arm, random_config(cid, arm, rng))
        viz.update_poses(rec, cid, bodies)
        for name, body in bodies.items():
            for (link, k), (pos, rot, geom_type) in pybullet_visual_poses(cid, body).items():
                path = f"meshcat/{name}/{link_name(cid, body, link)}/visual{k}"
                mirrored = world_transform(rec.tree, path)
                np.testing.assert_allclose(mirrored[:3, 3], pos, atol=1e-6)
                np.testing.assert_allclose(mirrored[:3, :3], rot, atol=1e-6)
                if geom_type == p.GEOM_CYLINDER:  # meshcat's +Y must be pybullet's +Z
                    axis = world_transform(rec.tree, path + "/cylinder")[:3, 1]
                    np.testing.assert_allclose(axis, rot[:, 2], atol=1e-6)


def test_arm_visuals_match_collision_shapes_through_centre_of_mass_frames(scene):
    """In jaco6.urdf each cylinder visual shares its origin with a capsule collision; pybullet reports
    collision frames relative to the centre of mass, a route independent of the link frames."""
    cid, bodies = scene
    arm = bodies["arm"]
    set_arm(cid, arm, random_config(cid, arm, np.random.default_rng(3)))
    rec = viz.Recorder()
    viz.mirror_bodies(rec, cid, {"arm": arm})
    checked = 0
    for link in range(p.getNumJoints(arm, physicsClientId=cid)):
        collisions = p.getCollisionShapeData(arm, link, physicsClientId=cid)
        if not collisions:
            continue
        com_pos, com_orn = p.getLinkState(arm, link, computeForwardKinematics=True, physicsClientId=cid)[:2]
        pos, orn = p.multiplyTransforms(com_pos, com_orn, collisions[0][5], collisions[0][6])
        mirrored = world_transform(rec.tree, f"meshcat/arm/{link_name(cid, arm, link)}/visual0")
        np.testing.assert_allclose(mirrored[:3, 3], pos, atol=1e-6)
        checked += 1
    assert checked >= 5


def test_base_link_frame_with_offset_inertial_frame(tmp_path):
    """getBasePositionAndOrientation is the inertial frame; visuals hang off the URDF link frame.
    The AABB (from the identical collision box) locates the geometry independently."""
    urdf = tmp_path / "offset.urdf"
    urdf.write_text("""<?xml version="1.0"?>
<robot name="offset"><link name="base">
  <inertial><origin xyz="0.1 0.2 0.3" rpy="0.3 0.2 0.1"/><mass value="1"/>
    <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>
  <visual><origin xyz="0.5 0 0"/><geometry><box size="0.1 0.1 0.1"/></geometry></visual>
  <collision><origin xyz="0.5 0 0"/><geometry><box size="0.1 0.1 0.1"/></geometry></collision>
</link></robot>""")
    cid = p.connect(p.DIRECT)
    try:
        orientation = p.getQuaternionFromEuler((0.0, 0.0, 0.7))
        from_urdf = p.loadURDF(str(urdf), basePosition=(1, 2, 3), baseOrientation=orientation, physicsClientId=cid)
        box = dict(halfExtents=(0.05, 0.05, 0.05), physicsClientId=cid)
        from_shapes = p.createMultiBody(
            1.0,
            p.createCollisionShape(p.GEOM_BOX, collisionFramePosition=(0.5, 0, 0), **box),
            p.createVisualShape(p.GEOM_BOX, visualFramePosition=(0.5, 0, 0), **box),
            basePosition=(1, 2, 3),
            baseOrientation=orientation,
            baseInertialFramePosition=(0.1, 0.2, 0.3),
            baseInertialFrameOrientation=p.getQuaternionFromEuler((0.3, 0.2, 0.1)),
            physicsClientId=cid,
        )
        bodies = {"urdf": from_urdf, "shapes": from_shapes}
        rec = viz.Recorder()
        viz.mirror_bodies(rec, cid, bodies)
        for name, body in bodies.items():
            centre = np.mean(p.getAABB(body, -1, physicsClientId=cid), axis=0)
            base_name = p.getBodyInfo(body, physicsClientId=cid)[0].decode()
            mirrored = world_transform(rec.tree, f"meshcat/{name}/{base_name}/visual0/box")
            np.testing.assert_allclose(mirrored[:3, 3], centre, atol=1e-6)
            np.testing.assert_allclose(centre, (1 + 0.5 * np.cos(0.7), 2 + 0.5 * np.sin(0.7), 3), atol=1e-6)
    finally:
        p.disconnect(cid)


def test_record_rollout_animates_moving_links_one_key_per_state(scene):
    cid, bodies = scene
    arm = bodies["arm"]
    rng = np.random.default_rng(11)
    states = [random_config(cid, arm, rng) for _ in range(7)]
    rec = viz.record_rollout(cid, bodies, states, lambda q: set_arm(cid, arm, q), fps=5, repetitions=2)
    command = umsgpack.unpackb(rec.tree.animation)
    assert command["options"] == {"play": True, "repetitions": 2}
    clips = {a["path"]: a["clip"] for a in command["animations"]}
    # only the arm's joints move; base, table and cup keep their static transforms
    assert set(clips) == {f"/meshcat/arm/{link_name(cid, arm, j)}" for j in range(7)}
    last_frames = {link_name(cid, arm, j): p.getLinkState(arm, j, physicsClientId=cid)[4] for j in range(7)}
    for path, clip in clips.items():
        assert clip["fps"] == 5
        for track in clip["tracks"]:
            assert [key["time"] for key in track["keys"]] == list(range(len(states)))
        position = next(t for t in clip["tracks"] if t["name"] == ".position")
        assert position["keys"][-1]["value"] == pytest.approx(last_frames[path.rsplit("/", 1)[1]], abs=1e-9)
    # the static scene starts at the first state
    set_arm(cid, arm, states[0])
    first = p.getLinkState(arm, 2, computeForwardKinematics=True, physicsClientId=cid)[4]
    assert world_transform(rec.tree, "meshcat/arm/link3")[:3, 3] == pytest.approx(first, abs=1e-9)


def test_ghosts_are_translucent_static_snapshots(scene):
    cid, bodies = scene
    arm = bodies["arm"]
    rng = np.random.default_rng(5)
    rec = viz.Recorder()
    viz.mirror_bodies(rec, cid, bodies)
    q_ghost = random_config(cid, arm, rng)
    set_arm(cid, arm, q_ghost)
    viz.add_ghost(rec, cid, arm, "ghost0", rgba=(0.0, 1.0, 0.0, 0.25))
    snapshot = world_transform(rec.tree, "meshcat/ghost0/hand/visual0")
    set_arm(cid, arm, random_config(cid, arm, rng))
    viz.update_poses(rec, cid, {"arm": arm})
    assert world_transform(rec.tree, "meshcat/ghost0/hand/visual0") == pytest.approx(snapshot)
    assert world_transform(rec.tree, "meshcat/arm/hand/visual0") != pytest.approx(snapshot)
    ghost_material = material(rec.tree, "meshcat/ghost0/link2/visual0/cylinder")
    assert ghost_material["color"] == 0x00FF00
    assert ghost_material["opacity"] == pytest.approx(0.25) and ghost_material["transparent"]


def test_mirroring_twice_replaces_old_geometry_and_meshes(scene, tmp_path):
    cid, bodies = scene
    rec = viz.Recorder()
    viz.mirror_bodies(rec, cid, {"thing": bodies["table"]})
    viz.mirror_bodies(rec, cid, {"thing": bodies["cup"]})
    assert set(node(rec.tree, "meshcat/thing/link0/visual0")) == {"cylinder"}

    obj = tmp_path / "tetra.obj"
    obj.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    mesh = p.createMultiBody(
        0,
        -1,
        p.createVisualShape(p.GEOM_MESH, fileName=str(obj), meshScale=(0.1, 0.2, 0.3), physicsClientId=cid),
        physicsClientId=cid,
    )
    raw = p.createMultiBody(
        0,
        -1,
        p.createVisualShape(
            p.GEOM_MESH, vertices=[[0, 0, 0], [1, 0, 0], [0, 1, 0]], indices=[0, 1, 2], physicsClientId=cid
        ),
        physicsClientId=cid,
    )
    with pytest.warns(UserWarning, match="mesh"):
        viz.mirror_bodies(rec, cid, {"mesh": mesh, "raw": raw})
    for body in (mesh, raw):
        p.removeBody(body, physicsClientId=cid)
    assert geometry(rec.tree, "meshcat/mesh/link0/visual0/mesh")["format"] == "obj"
    assert np.diag(world_transform(rec.tree, "meshcat/mesh/link0/visual0/mesh"))[:3] == pytest.approx([0.1, 0.2, 0.3])
    assert not node(rec.tree, "meshcat/raw/link0/visual0")

    plane = p.createMultiBody(0, -1, p.createVisualShape(p.GEOM_PLANE, physicsClientId=cid), physicsClientId=cid)
    viz.mirror_bodies(rec, cid, {"plane": plane})
    p.removeBody(plane, physicsClientId=cid)
    square = geometry(rec.tree, "meshcat/plane/link0/visual0/plane")
    top = world_transform(rec.tree, "meshcat/plane/link0/visual0/plane")[2, 3] + square["depth"] / 2
    assert (square["width"], square["height"], top) == pytest.approx((viz.PLANE_SIZE, viz.PLANE_SIZE, 0.0))


def test_show_and_save(scene, tmp_path):
    cid, bodies = scene
    rec = viz.Recorder()
    viz.mirror_bodies(rec, cid, bodies)
    shown = rec.show(height=300)
    assert shown._repr_html_() == shown.data
    # 300 px high at most, in the shape frame_view frames the scene for
    match = re.fullmatch(
        r'<div style="[^"]*max-width: 400px; aspect-ratio: 400 / 300;[^"]*"><iframe srcdoc="([^"]*)" '
        r"[^>]*></iframe></div>",
        shown.data,
    )
    assert viz.VIEW_ASPECT == 400 / 300
    assert match and html.unescape(match.group(1)) == rec.html()
    assert "<iframe srcdoc=" in rec._repr_html_()
    saved = rec.save(tmp_path / "scene.html")
    assert saved.read_text(encoding="utf-8") == rec.html()
    with pytest.raises(RuntimeError):
        rec.url


def test_import_hides_meshcats_zmq_deprecation_warning():
    # A fresh interpreter: in this process meshcat is already imported and pytest filters warnings.
    code = (
        "import warnings\n"
        "with warnings.catch_warnings(record=True) as caught:\n"
        "    warnings.simplefilter('always')\n"
        "    import vdtutorial.course.viz\n"
        "assert not [w for w in caught if 'zmq' in str(w.message)], caught\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)


def test_show_rgbd_two_images_and_metric_colour_bar():
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, size=(24, 32, 4), dtype=np.uint8)  # RGBA, as pybullet returns it
    depth = rng.uniform(0.3, 2.0, size=(24, 32))
    for rgbd in ((rgb, depth), np.dstack([rgb[..., :3] / 255.0, depth])):
        fig = viz.show_rgbd(rgbd, title="camera")
        images = [ax for ax in fig.axes if ax.images]
        assert len(images) == 2
        assert images[0].images[0].get_array().shape == (24, 32, 3)
        assert any(ax.get_ylabel() == "depth [m]" for ax in fig.axes)


def test_frames_animation_is_a_sized_player_that_needs_nothing_from_another_host():
    """The player stores every frame as a PNG, gives its image a size in pixels (a front end that scales images to
    their box's width lays one without a size out at 0 x 0) and loads no script, style sheet or font."""
    import matplotlib.image

    frames = [np.full((12, 16, 3), 40 * k, dtype=np.uint8) for k in range(4)]
    frames[1][2, 3] = (255, 0, 0)
    page = viz.frames_animation(frames, fps=8, scale=2).data
    urls = json.loads(re.search(r"const frames = (\[.*?\]);", page).group(1))
    decoded = [matplotlib.image.imread(io.BytesIO(base64.b64decode(u.split(",", 1)[1])), format="png") for u in urls]
    assert [np.round(d[..., :3] * 255).astype(np.uint8).tolist() for d in decoded] == [f.tolist() for f in frames]
    assert re.search(r'<img [^>]*width="32" height="24"[^>]*width: 32px; height: 24px; max-width: none', page)
    assert "setInterval(" in page and ", 125);" in page  # 8 frames a second
    assert not re.search(r"(?:src|href)\s*=\s*[\"']?(?:https?:)?//|@import|url\(", page)
    assert 'class="fa' not in page and "font-awesome" not in page
    with pytest.raises(ValueError, match="at least one frame"):
        viz.frames_animation([])


def _view_of(rec):
    """The recorded camera position and the page's look-at point, both in the world frame (z up)."""
    page = rec.html()
    x, y_up, minus_y = [
        c
        for c in recorded_commands(page)
        if c["type"] == "set_property" and c["path"] == "/Cameras/default/rotated/<object>"
    ][-1]["value"]
    look_at = json.loads(re.search(r"const lookAt = (.*?);", page).group(1))
    return np.array([x, -minus_y, y_up]), np.array([look_at[0], -look_at[2], look_at[1]])


def _screen_fractions(camera, look_at, points):
    """Where ``points`` fall in the view, as fractions of the half-width and half-height (|value| <= 1 in view)."""
    forward = (look_at - camera) / np.linalg.norm(look_at - camera)
    right = np.cross(forward, (0.0, 0.0, 1.0))
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    rays = points - camera
    depth = rays @ forward
    tan_half = np.tan(np.radians(viz.CAMERA_FOV_DEG / 2))
    return (rays @ right) / depth / (tan_half * viz.VIEW_ASPECT), (rays @ up) / depth / tan_half


def test_camera_frames_the_arm_and_the_cup(scene):
    """The camera looks at the arm and the cup and they fill most of the view (meshcat's own camera, 3 m away
    and aimed at the origin, showed them in 10-15 % of a wide frame): every corner of their shapes is in view,
    the picture touches the margins on both sides of one axis, and the table (the stage) is left out."""
    cid, bodies = scene
    rec = viz.Recorder()
    viz.mirror_bodies(rec, cid, bodies)
    camera, look_at = _view_of(rec)
    subject = viz.subject_corners(cid, {"arm": bodies["arm"], "cup": bodies["cup"]})
    assert np.allclose(viz.subject_corners(cid, bodies), subject), "the table is the stage, not framed"
    across, along = _screen_fractions(camera, look_at, subject)
    assert np.all(np.abs(across) <= 1) and np.all(np.abs(along) <= 1), "every corner is in view"
    widest = max(np.ptp(across), np.ptp(along)) / 2
    assert widest > 0.85, f"the arm and the cup span {widest:.0%} of the view"
    assert camera[2] > look_at[2] and np.linalg.norm(camera - look_at) < 2.0


def test_a_rollout_is_framed_over_all_its_states(scene):
    """record_rollout frames the whole motion: a pose the arm reaches late in the rollout is in view too."""
    cid, bodies = scene
    arm = bodies["arm"]
    start, stretched = np.zeros(6), np.array([1.2, 1.0, 0.5, 0.0, 0.0, 0.0])
    rec = viz.record_rollout(cid, bodies, [start, stretched], lambda q: set_arm(cid, arm, q))
    camera, look_at = _view_of(rec)
    for q in (start, stretched):
        set_arm(cid, arm, q)
        across, along = _screen_fractions(camera, look_at, viz.subject_corners(cid, bodies))
        assert np.all(np.abs(across) <= 1) and np.all(np.abs(along) <= 1)
    set_arm(cid, arm, start)


def test_compact_figures_shows_figures_as_palette_pngs_in_ipython():
    """After compact_figures, IPython formats a matplotlib figure as a PNG of at most 256 colours (PIL mode "P"),
    the same size as the full-colour one and with the same pixels where the figure uses few colours."""
    import io

    import matplotlib.pyplot as plt
    from IPython.core.interactiveshell import InteractiveShell
    from IPython.core.pylabtools import print_figure
    from PIL import Image

    shell = InteractiveShell.instance()
    try:
        fig, ax = plt.subplots(figsize=(3, 2))
        ax.plot([0, 1, 2], [0, 1, 0], color="C0")
        ax.set_title("a line")
        before = Image.open(io.BytesIO(print_figure(fig, "png", bbox_inches="tight")))  # the inline backend's PNG
        assert "image/png" not in shell.display_formatter.format(fig)[0]
        viz.compact_figures()
        png = shell.display_formatter.format(fig)[0]["image/png"]
        after = Image.open(io.BytesIO(png))
        plt.close(fig)
        assert after.mode == "P" and after.size == before.size
        assert np.mean(np.asarray(after.convert("RGB")) == np.asarray(before.convert("RGB"))) > 0.99
    finally:
        InteractiveShell.clear_instance()
