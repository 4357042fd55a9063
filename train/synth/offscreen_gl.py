"""The GL context of a depth + label renderer: single-sample framebuffer, shared EGL display.

Two things pyrender's offscreen renderer does by default would break exact labels or other
renderers, and this module undoes them (on the renderer's own context, patching no pyrender
function):

- **Multisampling.** pyrender draws into a 4x multisampled framebuffer and resolves it by
  averaging, which blends label colours at every silhouette and part edge (DESIGN.md measured
  3.5% wrong pixels). :func:`disable_multisampling` re-specifies its two renderbuffers with
  single-sample storage once pyrender has allocated them, and checks ``GL_RENDERBUFFER_SAMPLES``.
- **Display termination.** Closing one renderer terminates the EGL display that every context
  of the process shares. :func:`register_context` and :func:`release_offscreen` count this
  process's contexts and terminate the display only when the last one closes.
"""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import pyrender

__all__ = ["disable_multisampling", "register_context", "release_offscreen"]


def disable_multisampling(offscreen: pyrender.OffscreenRenderer) -> tuple[int, int]:
    """Make pyrender's multisampled offscreen framebuffer single-sampled.

    pyrender allocates the framebuffer lazily on its first render, with 4 samples, and keeps it
    while the viewport size stays the same. We let it allocate now (its own code, its formats)
    and then re-specify storage of the two renderbuffers with one sample. Re-specifying storage
    of an attached renderbuffer is ordinary GL; the framebuffer object stays the same.

    Returns:
        The ids of the colour and depth renderbuffers, to detect a re-allocation later.
    Raises:
        RuntimeError: when the result is not a complete single-sample framebuffer.
    """
    from OpenGL import GL

    renderer = offscreen._renderer
    offscreen._platform.make_current()
    renderer._configure_main_framebuffer()
    width, height = renderer._main_fb_dims
    # The same internal formats pyrender uses for these two renderbuffers.
    for buffer, internal_format in (
        (renderer._main_cb_ms, GL.GL_RGBA),
        (renderer._main_db_ms, GL.GL_DEPTH_COMPONENT24),
    ):
        GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, buffer)
        GL.glRenderbufferStorage(GL.GL_RENDERBUFFER, internal_format, width, height)
        samples = int(
            GL.glGetRenderbufferParameteriv(GL.GL_RENDERBUFFER, GL.GL_RENDERBUFFER_SAMPLES)
        )
        if samples != 0:
            raise RuntimeError(f"could not disable multisampling ({samples} samples remain)")
    GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, 0)
    GL.glBindFramebuffer(GL.GL_DRAW_FRAMEBUFFER, renderer._main_fb_ms)
    status = GL.glCheckFramebufferStatus(GL.GL_DRAW_FRAMEBUFFER)
    GL.glBindFramebuffer(GL.GL_DRAW_FRAMEBUFFER, 0)
    if status != GL.GL_FRAMEBUFFER_COMPLETE:
        raise RuntimeError(f"single-sample framebuffer is incomplete (status {status:#x})")
    # Dithering may perturb colours on some drivers; labels must come back bit-exact.
    GL.glDisable(GL.GL_DITHER)
    return int(renderer._main_cb_ms), int(renderer._main_db_ms)


# Live EGL contexts of DepthLabelRenderers in this process (see release_offscreen).
_live_contexts = 0
_live_lock = threading.Lock()


def _free_offscreen(offscreen: pyrender.OffscreenRenderer, terminate: bool) -> None:
    """Free an offscreen renderer's GL objects and context; terminate the display if asked.

    ``OffscreenRenderer.delete`` calls ``eglTerminate`` on the EGL display, which every EGL
    context of the process shares (the default device): closing one renderer would kill all
    others (``EGL_BAD_DISPLAY`` on their next call). We destroy only our own context and
    terminate the display only when ``terminate`` (the last of our renderers is closing), so
    that a process that is done rendering frees the display too. (Repeated create/close
    cycles were measured to settle at a flat memory footprint either way.) Other platforms
    (OSMesa, pyglet) use pyrender's own delete.
    """
    platform = offscreen._platform
    if platform is None:
        return
    if getattr(platform, "_egl_context", None) is None:
        offscreen.delete()
        return
    from OpenGL import EGL

    try:
        platform.make_current()
        offscreen._renderer.delete()
    finally:
        display, context = platform._egl_display, platform._egl_context
        EGL.eglMakeCurrent(display, EGL.EGL_NO_SURFACE, EGL.EGL_NO_SURFACE, EGL.EGL_NO_CONTEXT)
        EGL.eglDestroyContext(display, context)
        if terminate:
            EGL.eglTerminate(display)
        # Detach, so that the platform's and the OffscreenRenderer's __del__ (both end in
        # eglTerminate) find nothing to free.
        platform._egl_context = None
        platform._egl_display = None
        offscreen._renderer = None
        offscreen._platform = None


def register_context() -> None:
    """Count one more live EGL context of a renderer in this process."""
    global _live_contexts
    with _live_lock:
        _live_contexts += 1


def release_offscreen(offscreen: pyrender.OffscreenRenderer) -> None:
    """Free a registered renderer's context; terminate the EGL display if it was the last."""
    global _live_contexts
    with _live_lock:
        _live_contexts -= 1
        last = _live_contexts == 0
    _free_offscreen(offscreen, terminate=last)
