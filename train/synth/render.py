"""Headless rendering of labelled synthetic depth frames (pyrender on EGL).

:class:`DepthLabelRenderer` owns one ``pyrender.OffscreenRenderer`` and turns a triangle mesh in
camera coordinates (OpenCV frame: x right, y down, z forward, metres) with per-vertex body-part
labels into a metric depth image and an exact label image, in one render pass:

- depth (H, W) float32: metric camera z, 0 = background (nothing, or outside [znear, zfar]);
- labels (H, W) uint8: the label of the triangle visible at each pixel centre, 0 = background.

How the labels are made exact:

- **Per-face labels.** A face takes the majority label of its three vertices (the first
  vertex's label when all three differ; :func:`face_labels_from_vertices`, in
  :mod:`train.synth.label_mesh`). Vertices shared by
  faces of different labels are duplicated (:func:`split_by_label`), so every vertex of a face
  carries the face's label and the interpolated colour is constant over the face.
- **Flat colour.** The label is written as the red channel ``label / 255`` of an unlit
  per-vertex colour (``RenderFlags.FLAT``); interpolating three equal values and converting to
  8 bits gives the label back exactly. One primitive, one draw call per frame.
- **No multisampling.** pyrender's offscreen path draws into a 4x multisampled framebuffer and
  resolves it by averaging, which blends label colours at every silhouette and part edge
  (DESIGN.md measured 3.5% wrong pixels). After pyrender allocates that framebuffer (once, on a
  fixed viewport) we re-specify its two renderbuffers with single-sample storage
  (:func:`train.synth.offscreen_gl.disable_multisampling`): every fragment then covers its
  whole pixel and the "resolve" blit is a plain copy. No pyrender function is patched; the
  change is local to this renderer's GL context and is checked by querying
  ``GL_RENDERBUFFER_SAMPLES``.

Camera conventions (:func:`make_pyrender_camera`): pyrender cameras follow OpenGL (x right,
y up, looking down -z). The camera node gets the pose ``diag(1, -1, -1, 1)``, which maps OpenCV
camera coordinates to pyrender's, so vertices are uploaded unchanged. For the principal point,
``pyrender.IntrinsicsCamera``'s projection puts a camera point at window coordinate
``x_w = fx x / z + cx`` (pixel edges at integers, so pixel centres at ``i + 0.5``) and, after
pyrender flips the read-back image, at row coordinate ``fy y / z + cy`` measured from the top
edge. OpenCV puts pixel centres at integers, so we pass ``cx + 0.5, cy + 0.5``: then a point
projected by :func:`shared.camera.points_to_pixels` to (u, v) is rendered in pixel
``(round(u), round(v))``.

Per frame, only vertex positions change: they are written into the existing GL vertex buffer
with ``glBufferSubData`` (no new GL objects); a new topology or label set rebuilds the mesh
node once. Measured on the 2-core project CPU (Mesa llvmpipe, under load from another job),
320x240, the native anny body (27,420 triangles) re-posed every frame: about 210 frames/s
(4.8 ms) with in-place upload, about 180 frames/s when rebuilding the mesh node every frame
instead, and about 250-270 frames/s with ``cull_back_faces=True`` (identical labels on the
closed anny body in 24 views around it).

Several renderers may live in one process (each owns a context; all share the EGL display,
which is therefore terminated only when the last one closes). ``PYOPENGL_PLATFORM=egl`` is set
(unless already set) on import, before anything imports PyOpenGL; pyrender itself is imported
lazily so that ``import train.synth.render`` is cheap.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
from depthmocap.shared.camera import Intrinsics
from depthmocap.train.synth import offscreen_gl
from depthmocap.train.synth.label_mesh import (
    SplitMesh,
    as_uint8_labels,
    check_faces,
    face_labels_from_vertices,
    split_by_label,
)

# PyOpenGL picks its platform when first imported: set it before any import of OpenGL/pyrender.
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

if TYPE_CHECKING:
    import pyrender

__all__ = [
    "EGL_HELP",
    "CAMERA_POSE_OPENCV_TO_PYRENDER",
    "RenderedFrame",
    "SplitMesh",
    "DepthLabelRenderer",
    "face_labels_from_vertices",
    "split_by_label",
    "make_pyrender_camera",
    "render_depth_labels",
]

EGL_HELP = (
    "headless rendering needs EGL with Mesa: install it with "
    "`apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri` (plus libgl1 libopengl0) and run "
    "with PYOPENGL_PLATFORM=egl (train.synth.render sets it when unset; it must be set before "
    "anything imports OpenGL or pyrender)"
)

# Pose of pyrender's (OpenGL) camera in the OpenCV camera frame: same x, flipped y and z.
CAMERA_POSE_OPENCV_TO_PYRENDER = np.diag([1.0, -1.0, -1.0, 1.0])

# Floats per vertex in pyrender's interleaved vertex buffer: position (3) + colour_0 (4).
_FLOATS_PER_VERTEX = 7


class RenderedFrame(NamedTuple):
    """One rendered frame.

    Attributes:
        depth: (H, W) float32 metric z in metres; 0 = background.
        labels: (H, W) uint8 label of the visible triangle; 0 = background.
    """

    depth: np.ndarray
    labels: np.ndarray


def make_pyrender_camera(
    intrinsics: Intrinsics, znear: float, zfar: float
) -> pyrender.IntrinsicsCamera:
    """pyrender camera that reproduces OpenCV pinhole ``intrinsics``.

    The principal point moves by half a pixel: pyrender/OpenGL put pixel centres at
    ``i + 0.5``, OpenCV at ``i`` (derivation in the module docstring). Pose the camera node with
    :data:`CAMERA_POSE_OPENCV_TO_PYRENDER` so that scene coordinates are OpenCV camera
    coordinates.
    """
    import pyrender

    return pyrender.IntrinsicsCamera(
        fx=intrinsics.fx,
        fy=intrinsics.fy,
        cx=intrinsics.cx + 0.5,
        cy=intrinsics.cy + 0.5,
        znear=znear,
        zfar=zfar,
    )


class DepthLabelRenderer:
    """Depth + body-part label images of a triangle mesh, headless (EGL), reusable per frame.

    Args:
        intrinsics: camera of the output images (OpenCV convention).
        znear: near clipping plane, metres; closer surfaces are not drawn.
        zfar: far clipping plane, metres; farther surfaces are not drawn.
        cull_back_faces: skip triangles facing away from the camera. Faster, and right for a
            closed, consistently outward-wound mesh (counter-clockwise seen from outside); keep
            it off for open or inconsistently wound meshes.

    Use as a context manager or call :meth:`close`. The mesh topology and labels are set with
    :meth:`set_mesh` (or passed to :meth:`render`, which re-uses them while unchanged); each
    :meth:`render` then uploads new vertex positions into the existing GL buffer.

    Example::

        with DepthLabelRenderer(Intrinsics.kinect_v1(320)) as r:
            r.set_mesh(faces, vertex_labels)
            for verts in frames:
                depth, labels = r.render(verts)

    Raises:
        RuntimeError: when pyrender or EGL cannot be initialised (the message names the fix).
    """

    def __init__(
        self,
        intrinsics: Intrinsics,
        znear: float = 0.3,
        zfar: float = 10.0,
        *,
        cull_back_faces: bool = False,
    ) -> None:
        intrinsics.validate()
        if not 0.0 < znear < zfar:
            raise ValueError(f"need 0 < znear < zfar, got znear={znear}, zfar={zfar}")
        self.intrinsics = intrinsics
        self.znear = float(znear)
        self.zfar = float(zfar)
        self.cull_back_faces = bool(cull_back_faces)
        self._offscreen: Any = None
        self._mesh_node: Any = None
        self._split: SplitMesh | None = None
        self._faces_key: tuple[np.ndarray, str, np.ndarray] | None = None
        self._max_index = -1
        self._interleaved: np.ndarray | None = None
        self._vbo: int | None = None

        try:
            import pyrender
        except ImportError as err:
            raise RuntimeError(
                f"pyrender is not installed ({err}); install the training extra: "
                "`pip install -e .[train]`"
            ) from err
        try:
            offscreen = pyrender.OffscreenRenderer(intrinsics.width, intrinsics.height)
        except Exception as err:  # EGL failures surface as assorted error types
            # PyOpenGL's GLError text spans many lines: keep the gist on one.
            cause = " ".join(f"{type(err).__name__}: {err}".split())[:160]
            raise RuntimeError(
                f"cannot create an EGL OpenGL context ({cause}); {EGL_HELP}"
            ) from err
        offscreen_gl.register_context()
        self._offscreen = offscreen
        try:
            self._renderbuffers = offscreen_gl.disable_multisampling(offscreen)
        except Exception:
            self.close()
            raise
        self._pyrender = pyrender
        self._flags = pyrender.RenderFlags.FLAT
        self._material = pyrender.MetallicRoughnessMaterial(
            # Floats: pyrender reads integer colours as 0-255.
            baseColorFactor=(1.0, 1.0, 1.0, 1.0),
            alphaMode="OPAQUE",
            doubleSided=not self.cull_back_faces,
        )
        self._scene = pyrender.Scene(bg_color=(0.0, 0.0, 0.0, 0.0), ambient_light=(0.0, 0.0, 0.0))
        self._scene.add(
            make_pyrender_camera(intrinsics, self.znear, self.zfar),
            pose=CAMERA_POSE_OPENCV_TO_PYRENDER,
        )

    # ---- lifecycle -------------------------------------------------------------------------

    @property
    def closed(self) -> bool:
        """True after :meth:`close`."""
        return self._offscreen is None

    def close(self) -> None:
        """Free the GL context and all GL objects. Safe to call twice."""
        offscreen, self._offscreen = self._offscreen, None
        self._mesh_node = None
        self._vbo = None
        if offscreen is not None:
            offscreen_gl.release_offscreen(offscreen)

    def __enter__(self) -> DepthLabelRenderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # interpreter shutdown: GL may already be gone
            pass

    # ---- mesh ------------------------------------------------------------------------------

    def set_mesh(
        self,
        faces: np.ndarray,
        vertex_labels: np.ndarray | None = None,
        *,
        face_labels: np.ndarray | None = None,
    ) -> None:
        """Set the topology and labels used by the following :meth:`render` calls.

        Args:
            faces: (F, 3) integer vertex indices.
            vertex_labels: (V,) labels in [0, 255]; faces take their majority label
                (:func:`face_labels_from_vertices`). Give this or ``face_labels``.
            face_labels: (F,) labels in [0, 255], one per face.
        """
        if (vertex_labels is None) == (face_labels is None):
            raise ValueError("give exactly one of vertex_labels and face_labels")
        faces = check_faces(faces)
        if vertex_labels is not None:
            vertex_labels = np.asarray(vertex_labels)
            if vertex_labels.ndim != 1:
                raise ValueError(f"vertex_labels must be (V,), got {vertex_labels.shape}")
            if faces.size and faces.max() >= len(vertex_labels):
                raise ValueError(
                    f"faces index vertex {faces.max()} but there are {len(vertex_labels)} labels"
                )
            vertex_labels = as_uint8_labels(vertex_labels, len(vertex_labels), "vertex_labels")
            per_face = face_labels_from_vertices(faces, vertex_labels)
            key = (faces.copy(), "vertex", vertex_labels.copy())
        else:
            per_face = as_uint8_labels(face_labels, len(faces), "face_labels")
            key = (faces.copy(), "face", per_face.copy())
        self._faces_key = key
        self._split = split_by_label(faces, per_face)
        self._max_index = int(faces.max()) if faces.size else -1
        n = len(self._split.source)
        self._interleaved = np.zeros((n, _FLOATS_PER_VERTEX), dtype=np.float32)
        self._interleaved[:, 3] = self._split.labels / np.float32(255.0)  # red = label
        self._interleaved[:, 6] = 1.0  # opaque
        self._drop_mesh_node()

    def _same_mesh(
        self, faces: np.ndarray, vertex_labels: np.ndarray | None, face_labels: np.ndarray | None
    ) -> bool:
        if self._faces_key is None:
            return False
        key_faces, key_kind, key_labels = self._faces_key
        kind, labels = (
            ("vertex", vertex_labels) if vertex_labels is not None else ("face", face_labels)
        )
        return (
            labels is not None
            and kind == key_kind
            and np.array_equal(key_faces, faces)
            and np.array_equal(key_labels, labels)
        )

    def _drop_mesh_node(self) -> None:
        # pyrender frees the primitive's GL buffers on the next render, once it is off the scene.
        if self._mesh_node is not None:
            self._scene.remove_node(self._mesh_node)
        self._mesh_node = None
        self._vbo = None

    def _add_mesh_node(self) -> None:
        """A new mesh node from the current interleaved array (GL upload on the next render)."""
        assert self._split is not None and self._interleaved is not None
        primitive = self._pyrender.Primitive(
            positions=self._interleaved[:, :3],
            color_0=self._interleaved[:, 3:],
            indices=self._split.faces,
            material=self._material,
        )
        self._mesh_node = self._scene.add(self._pyrender.Mesh([primitive]))

    def _upload_positions(self) -> None:
        """Overwrite the vertex buffer in place (same size, same layout as pyrender's)."""
        from OpenGL import GL

        assert self._interleaved is not None
        GL.glBindBuffer(GL.GL_ARRAY_BUFFER, self._vbo)
        GL.glBufferSubData(GL.GL_ARRAY_BUFFER, 0, self._interleaved.nbytes, self._interleaved)
        GL.glBindBuffer(GL.GL_ARRAY_BUFFER, 0)

    def _find_vertex_buffer(self) -> int | None:
        """Id of the primitive's interleaved vertex buffer, if its layout is the expected one.

        pyrender packs position and colour_0 into its first buffer; should a future version
        lay it out differently, the size check fails and we rebuild the node per frame instead.
        """
        from OpenGL import GL

        primitive = self._mesh_node.mesh.primitives[0]
        buffers = getattr(primitive, "_buffers", None)
        if not buffers:
            return None
        GL.glBindBuffer(GL.GL_ARRAY_BUFFER, buffers[0])
        size = int(GL.glGetBufferParameteriv(GL.GL_ARRAY_BUFFER, GL.GL_BUFFER_SIZE))
        GL.glBindBuffer(GL.GL_ARRAY_BUFFER, 0)
        assert self._interleaved is not None
        return int(buffers[0]) if size == self._interleaved.nbytes else None

    # ---- rendering -------------------------------------------------------------------------

    def render(
        self,
        vertices: np.ndarray,
        faces: np.ndarray | None = None,
        vertex_labels: np.ndarray | None = None,
        *,
        face_labels: np.ndarray | None = None,
    ) -> RenderedFrame:
        """Render depth and labels of the mesh with these vertex positions.

        Args:
            vertices: (V, 3) float positions in the OpenCV camera frame, metres.
            faces: (F, 3) integer indices; when given with ``vertex_labels`` or
                ``face_labels``, the mesh is (re)set unless it equals the current one. When
                omitted, the mesh of the last :meth:`set_mesh` is used.
            vertex_labels: (V,) labels, see :meth:`set_mesh`.
            face_labels: (F,) labels, see :meth:`set_mesh`.
        Returns:
            :class:`RenderedFrame` with depth (H, W) float32 metres and labels (H, W) uint8,
            both 0 at background.
        """
        if self.closed:
            raise RuntimeError("renderer is closed")
        if faces is not None:
            faces = check_faces(faces)
            if not self._same_mesh(faces, vertex_labels, face_labels):
                self.set_mesh(faces, vertex_labels, face_labels=face_labels)
        elif vertex_labels is not None or face_labels is not None:
            raise ValueError("labels given without faces")
        if self._split is None:
            raise ValueError("no mesh: call set_mesh() or pass faces and labels")

        vertices = np.asarray(vertices)
        if vertices.ndim != 2 or vertices.shape[1] != 3:
            raise ValueError(f"vertices must be (V, 3), got {vertices.shape}")
        if vertices.shape[0] <= self._max_index:
            raise ValueError(
                f"faces index vertex {self._max_index} but only {vertices.shape[0]} vertices given"
            )
        h, w = self.intrinsics.height, self.intrinsics.width
        if len(self._split.faces) == 0:
            return RenderedFrame(np.zeros((h, w), np.float32), np.zeros((h, w), np.uint8))

        assert self._interleaved is not None
        self._interleaved[:, :3] = vertices[self._split.source]
        if not np.isfinite(self._interleaved[:, :3]).all():
            raise ValueError("vertices contain NaN or infinity")

        offscreen = self._offscreen
        offscreen._platform.make_current()
        if self._mesh_node is not None and self._vbo is not None:
            self._upload_positions()
        else:
            # First frame of this mesh, or the in-place path is unavailable: new GL buffers.
            self._drop_mesh_node()
            self._add_mesh_node()
        color, depth = offscreen.render(self._scene, self._flags)
        if self._vbo is None:
            self._vbo = self._find_vertex_buffer()

        renderer = offscreen._renderer
        if (int(renderer._main_cb_ms), int(renderer._main_db_ms)) != self._renderbuffers:
            raise RuntimeError("pyrender re-allocated its framebuffer; multisampling is back on")
        return RenderedFrame(
            depth=np.ascontiguousarray(depth, dtype=np.float32),
            labels=np.ascontiguousarray(color[..., 0]),
        )

    @property
    def samples(self) -> int:
        """Samples per pixel of the framebuffer drawn into (0 = no multisampling)."""
        from OpenGL import GL

        if self.closed:
            raise RuntimeError("renderer is closed")
        self._offscreen._platform.make_current()
        GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, self._offscreen._renderer._main_cb_ms)
        samples = GL.glGetRenderbufferParameteriv(GL.GL_RENDERBUFFER, GL.GL_RENDERBUFFER_SAMPLES)
        GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, 0)
        return int(samples)


def render_depth_labels(
    vertices: np.ndarray,
    faces: np.ndarray,
    vertex_labels: np.ndarray,
    intrinsics: Intrinsics,
    znear: float = 0.3,
    zfar: float = 10.0,
) -> RenderedFrame:
    """One-off render (creates and frees a GL context: use :class:`DepthLabelRenderer` for
    sequences).

    Args:
        vertices: (V, 3) OpenCV camera-frame positions, metres.
        faces: (F, 3) vertex indices.
        vertex_labels: (V,) labels in [0, 255].
        intrinsics: output camera.
    Returns:
        :class:`RenderedFrame` (depth (H, W) float32, labels (H, W) uint8).
    """
    with DepthLabelRenderer(intrinsics, znear, zfar) as renderer:
        return renderer.render(vertices, faces, vertex_labels)
