"""Headless template rendering with pyrender on EGL (Mesa), and the thread that owns the GL context.

A template is rendered once per viewpoint, a little larger than the patch (64 * sqrt(2) px), so that
every in-plane variant is that render turned about its centre and cropped: no extra render per roll.
The render's pixel grid is the patch's metric window: `window_mm` at the render distance spans `size` px.
"""

from __future__ import annotations

import os
import queue
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import Future
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
# Mesa's software rasteriser (llvmpipe) draws on the thread that asks, not on a pool of its own: a template
# is 91 px a side, too small for the hand-off to pay. The 301 renders of a 20k-face mesh: 0.97-1.0 s and
# 1.04-1.10 CPU-seconds with its default pool (a thread a core) against 0.84-0.87 s and as many CPU-seconds
# (the same pixels; docs/experiments.md, "A registration's CPU"). Read when the first GL context is made.
os.environ.setdefault("LP_NUM_THREADS", "0")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

if not hasattr(np, "infty"):  # pyrender 0.1.45 still says np.infty, gone in numpy 2
    np.infty = np.inf  # type: ignore[attr-defined]

import pyrender  # noqa: E402
import trimesh  # noqa: E402
from pyrender.shader_program import ShaderProgramCache  # noqa: E402

from index.geometry.pose import OPENGL_FROM_OPENCV, View, opengl_camera_pose, view_to_pose  # noqa: E402
from index.templates.mesh import simplify  # noqa: E402

SHADER_DIR = Path(__file__).parent / "shaders"
T = TypeVar("T")
# Why no template shows the object; the camera looks at the object's origin, from 400 mm by default.
INVISIBLE = "the object is invisible in every template: check its units, and that its origin lies on or in it"


@dataclass(frozen=True)
class Lighting:
    """Light for templates. Directions are in the camera frame (OpenCV axes), so every view is lit alike."""

    ambient: float = 0.35
    #: (direction the light travels, intensity); the default is a headlight slightly from above-left.
    lights: tuple[tuple[tuple[float, float, float], float], ...] = (((0.3, 0.4, 1.0), 0.75),)


@dataclass
class Templates:
    """Rendered views of one object. rgb: (N, S, S, 3) uint8; depth: (N, S, S) float32 mm, 0 = empty."""

    views: list[View]
    rgb: np.ndarray
    depth: np.ndarray
    window_mm: float
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def visible(self) -> bool:
        """Whether the object shows in any of them; if not, every template is black (see INVISIBLE)."""
        return bool((self.depth > 0).any())


@dataclass(frozen=True)
class Uprights:
    """Upright renders of `views`' viewpoints, `render_size(size)` px a side (`Renderer.render_upright`):
    view i is render `of_view[i]` turned by its in-plane angle and cropped (`rotate_crop`).
    rgb: (V, B, B, 3) uint8; depth: (V, B, B) float32 mm, 0 = empty."""

    views: list[View]
    of_view: np.ndarray
    rgb: np.ndarray
    depth: np.ndarray
    size: int
    window_mm: float

    def templates(self, idx: Sequence[int] | None = None, colour: bool = True) -> Templates:
        """The templates of the views at `idx` (default all), in that order. Without `colour` (a depth
        model's, which never reads it) their rgb is left black and not turned: turning it is most of
        the turn's cost."""
        idx = range(len(self.views)) if idx is None else idx
        s = self.size
        rgb = np.zeros((len(idx), s, s, 3), np.uint8)
        depth = np.zeros((len(idx), s, s), np.float32)
        for j, i in enumerate(idx):
            k = self.of_view[i]
            if colour:
                rgb[j], depth[j] = rotate_crop(self.rgb[k], self.depth[k], self.views[i].inplane, s)
            else:
                depth[j] = rotate_crop_depth(self.depth[k], self.views[i].inplane, s)
        return Templates([self.views[i] for i in idx], rgb, depth, self.window_mm)


def render_size(size: int) -> int:
    """Side of the render that holds a `size` patch turned by any angle."""
    return int(np.ceil(size * np.sqrt(2))) | 1  # odd, so the centre is a pixel centre both ways


@dataclass
class _Rig:
    """A scene's camera node and its lights (node, direction in OpenCV camera axes)."""

    camera: pyrender.Node
    lights: list[tuple[pyrender.Node, np.ndarray]]


class Renderer:
    """Renders meshes from views. Owns an EGL context: create and use it on one thread only."""

    def __init__(
        self,
        size: int = 64,
        window_mm: float = 200.0,
        lighting: Lighting | None = None,
        max_faces: int = 6000,
    ):
        # Level of detail: a 64 px patch shows no more than a few thousand faces, and Mesa's software
        # vertex stage costs ~0.4 us a vertex, so heavier meshes are decimated for templates.
        self.size, self.window_mm, self.max_faces = size, window_mm, max_faces
        self.lighting = lighting or Lighting()
        self.big = render_size(size)
        self._thread = threading.get_ident()
        self._gl = pyrender.OffscreenRenderer(self.big, self.big)
        self._gl._renderer._program_cache = ShaderProgramCache(shader_dir=str(SHADER_DIR))

    def _check_thread(self) -> None:
        if threading.get_ident() != self._thread:
            raise RuntimeError("a Renderer is bound to the thread that created it (EGL context)")

    def render(
        self,
        mesh: trimesh.Trimesh,
        views: Sequence[View],
        lighting: Lighting | None = None,
        progress: Callable[[int], object] | None = None,
    ) -> Templates:
        """RGB and depth patches (size x size) of `mesh` from `views`, each centred on the object origin.

        Views that share azimuth, elevation and distance are rendered once and turned in-plane."""
        return self.render_upright(mesh, views, lighting, progress).templates()

    def render_upright(
        self,
        mesh: trimesh.Trimesh,
        views: Sequence[View],
        lighting: Lighting | None = None,
        progress: Callable[[int], object] | None = None,
    ) -> Uprights:
        """The renders `render` turns into the templates of `views`: one per viewpoint (azimuth,
        elevation, distance). Turning them (`Uprights.templates`) needs no GL context, so a registration
        does it on its embedding threads, off this thread's back (`index.templates.register`)."""
        self._check_thread()
        lighting = lighting or self.lighting
        if len(mesh.faces) > self.max_faces:
            mesh = simplify(mesh, self.max_faces)
        scene = self._scene(mesh, lighting)
        groups: dict[tuple[float, float, float], list[int]] = {}
        for i, v in enumerate(views):
            groups.setdefault((v.azimuth, v.elevation, v.distance), []).append(i)
        b = self.big
        rgb = np.zeros((len(groups), b, b, 3), np.uint8)
        depth = np.zeros((len(groups), b, b), np.float32)
        of_view = np.zeros(len(views), np.int64)
        rig = self._rig(scene, lighting)  # camera and lights added once, moved for every view
        for k, ((az, el, dist), idx) in enumerate(groups.items()):
            rgb[k], depth[k] = self._render_one(scene, View(az, el, 0.0, dist), rig)
            of_view[idx] = k
            if progress:
                progress(len(idx))
        return Uprights(list(views), of_view, rgb, depth, self.size, self.window_mm)

    def render_frame(
        self,
        meshes: Sequence[tuple[trimesh.Trimesh, np.ndarray, np.ndarray]],
        K: np.ndarray,
        width: int,
        height: int,
        lighting: Lighting | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """A full camera frame of meshes at BOP poses [(mesh, R_m2c, t_m2c mm)], OpenCV intrinsics K.

        Returns rgb (H, W, 3) uint8 and depth (H, W) float32 mm (0 = nothing), as a sensor would."""
        self._check_thread()
        lighting = lighting or self.lighting
        a = lighting.ambient
        scene = pyrender.Scene(bg_color=[0, 0, 0, 0], ambient_light=[a, a, a])
        for mesh, R, t in meshes:
            pose = np.eye(4)
            pose[:3, :3], pose[:3, 3] = OPENGL_FROM_OPENCV @ R, OPENGL_FROM_OPENCV @ np.ravel(t)
            scene.add(pyrender.Mesh.from_trimesh(mesh, smooth=True), pose=pose)
        # The camera sits at the scene origin, OpenGL axes; pixel centres at i + 0.5 in pyrender.
        cam = pyrender.IntrinsicsCamera(
            K[0, 0], K[1, 1], K[0, 2] + 0.5, K[1, 2] + 0.5, znear=10.0, zfar=20000.0
        )
        scene.add(cam, pose=np.eye(4))
        for direction, intensity in lighting.lights:
            d = OPENGL_FROM_OPENCV @ (np.asarray(direction, float) / np.linalg.norm(direction))
            scene.add(pyrender.DirectionalLight(intensity=intensity), pose=_light_pose(d))
        self._gl.viewport_width, self._gl.viewport_height = width, height
        try:
            color, depth = self._gl.render(scene)
        finally:
            self._gl.viewport_width = self._gl.viewport_height = self.big
        return np.ascontiguousarray(color[..., :3]), depth.astype(np.float32)

    def _scene(self, mesh: trimesh.Trimesh, lighting: Lighting) -> pyrender.Scene:
        a = lighting.ambient
        scene = pyrender.Scene(bg_color=[0, 0, 0, 0], ambient_light=[a, a, a])
        scene.add(pyrender.Mesh.from_trimesh(mesh, smooth=True))
        return scene

    def _rig(self, scene: pyrender.Scene, lighting: Lighting) -> _Rig:
        c = self.big / 2  # pyrender puts pixel centres at i + 0.5: this is the centre pixel's centre
        cam = scene.add(pyrender.IntrinsicsCamera(1.0, 1.0, c, c, znear=1.0, zfar=2.0), pose=np.eye(4))
        lights = [
            (
                scene.add(pyrender.DirectionalLight(intensity=i), pose=np.eye(4)),
                np.asarray(d, float) / np.linalg.norm(d),
            )
            for d, i in lighting.lights
        ]
        return _Rig(cam, lights)

    def _render_one(self, scene: pyrender.Scene, view: View, rig: _Rig) -> tuple[np.ndarray, np.ndarray]:
        """One render at in-plane 0 through `rig`, which it moves (setting a pose is cheap in pyrender;
        adding and removing a camera and lights for every view cost ~10% of a registration)."""
        R, t = view_to_pose(View(view.azimuth, view.elevation, 0.0, view.distance))
        cam = rig.camera.camera
        cam.fx = cam.fy = self.size * view.distance / self.window_mm  # the window spans `size` px there
        cam.znear, cam.zfar = max(1.0, view.distance / 20), view.distance * 20
        scene.set_pose(rig.camera, opengl_camera_pose(R, t))
        for node, direction in rig.lights:
            # A pyrender light shines along its node's -z; pose it so that -z is `direction` (given in
            # OpenCV camera axes), expressed in the object frame.
            scene.set_pose(node, _light_pose(R.T @ direction))
        color, depth = self._gl.render(scene)
        return np.ascontiguousarray(color[..., :3]), depth.astype(np.float32)

    def close(self) -> None:
        """Frees this renderer's GL resources and context, but not the EGL display: every context of the
        process shares that display, and pyrender's own `delete` terminates it under the others' feet."""
        from OpenGL.EGL import EGL_NO_CONTEXT, EGL_NO_SURFACE, eglDestroyContext, eglMakeCurrent

        gl = self._gl
        platform = gl._platform
        platform.make_current()
        gl._renderer.delete()
        eglMakeCurrent(platform._egl_display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT)
        eglDestroyContext(platform._egl_display, platform._egl_context)
        platform._egl_context = platform._egl_display = None
        gl._renderer = gl._platform = None  # so pyrender's __del__ has nothing left to terminate


def _light_pose(direction: np.ndarray) -> np.ndarray:
    z = -direction / np.linalg.norm(direction)
    x = np.cross([0.0, 0.0, 1.0], z) if abs(z[2]) < 0.99 else np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    pose = np.eye(4)
    pose[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    return pose


def rotate_crop(
    rgb: np.ndarray, depth: np.ndarray, inplane: float, size: int
) -> tuple[np.ndarray, np.ndarray]:
    """Turns a centred render by `inplane` degrees counter-clockwise and crops the central size x size."""
    M = _turn(rgb.shape[0], inplane, size)
    return cv2.warpAffine(rgb, M, (size, size), flags=cv2.INTER_LINEAR), rotate_crop_depth(depth, M, size)


def rotate_crop_depth(depth: np.ndarray, turn: float | np.ndarray, size: int) -> np.ndarray:
    """`rotate_crop`'s depth alone; `turn`: the in-plane angle, or its matrix (`_turn`)."""
    M = _turn(depth.shape[0], turn, size) if isinstance(turn, float | int) else turn
    return cv2.warpAffine(depth, M, (size, size), flags=cv2.INTER_NEAREST)


def _turn(big: int, inplane: float, size: int) -> np.ndarray:
    """The affine map of `rotate_crop`: a turn about the render's centre, shifted so the crop is the output."""
    c = (big - 1) / 2
    # positive = counter-clockwise in the image
    M = np.asarray(cv2.getRotationMatrix2D((c, c), float(inplane), 1.0), np.float64)
    M[:, 2] -= (big - size) / 2
    return M


class RenderWorker:
    """One thread that owns a Renderer; other threads hand it work and wait on a Future."""

    def __init__(self, **renderer_kwargs: Any):
        self._jobs: queue.Queue[tuple[Callable[[Renderer], Any], Future] | None] = queue.Queue()
        self._ready: Future = Future()
        self._thread = threading.Thread(target=self._run, args=(renderer_kwargs,), daemon=True, name="render")
        self._thread.start()
        self._ready.result()  # surfaces EGL set-up errors in the caller

    def _run(self, kwargs: dict[str, Any]) -> None:
        try:
            renderer = Renderer(**kwargs)
        except Exception as e:
            self._ready.set_exception(e)
            return
        self._ready.set_result(True)
        while (job := self._jobs.get()) is not None:
            fn, fut = job
            if fut.set_running_or_notify_cancel():
                try:
                    fut.set_result(fn(renderer))
                except BaseException as e:
                    fut.set_exception(e)
        renderer.close()

    def submit(self, fn: Callable[[Renderer], T]) -> Future[T]:
        fut: Future[T] = Future()
        self._jobs.put((fn, fut))
        return fut

    def close(self) -> None:
        self._jobs.put(None)
        self._thread.join(timeout=10)
