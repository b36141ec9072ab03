"""Headless OpenGL contexts: EGL, with OSMesa as the fallback, and the choice between them.

``PYOPENGL_PLATFORM`` is honoured when set; otherwise EGL is probed (in a subprocess, because
PyOpenGL fixes its platform at import) and OSMesa is the fallback.

Example::

    platform = select_backend("auto")           # "egl" or "osmesa"; RenderBackendError says what to install
    ctx = create_context(platform, 320, 192)
"""
from __future__ import annotations

import ctypes
import os
import subprocess
import sys

BACKENDS = ("egl", "osmesa")

INSTALL_HINT = (
    "no working headless OpenGL back end: EGL (Debian: apt-get install libegl1 libegl-mesa0 "
    "libgl1-mesa-dri) or OSMesa (apt-get install libosmesa6) is needed; "
    "set PYOPENGL_PLATFORM=egl or =osmesa to force one"
)


class RenderBackendError(RuntimeError):
    """No usable OpenGL back end, or the back end failed; the message says what to install."""


_PROBE = r"""
import os, sys
os.environ["PYOPENGL_PLATFORM"] = sys.argv[1]
sys.path.insert(0, sys.argv[2])
from synth.gl_context import create_context
ctx = create_context(sys.argv[1], 16, 16)
from OpenGL import GL
print(GL.glGetString(GL.GL_RENDERER).decode())
"""


def select_backend(requested: str = "auto") -> str:
    """Pick the OpenGL platform: `requested`, else $PYOPENGL_PLATFORM, else EGL, else OSMesa.

    Sets $PYOPENGL_PLATFORM so worker processes inherit the choice.
    """
    env = os.environ.get("PYOPENGL_PLATFORM", "").strip().lower()
    egl_device()  # a malformed MCDP_EGL_DEVICE: one line naming it, before any probe
    if requested not in ("auto",) + BACKENDS:
        raise ValueError(f"render.backend must be one of auto, egl, osmesa, got {requested!r}")
    if requested != "auto":
        if "OpenGL" in sys.modules and env and env != requested:
            raise RenderBackendError(
                f"render.backend={requested} but OpenGL was already imported with PYOPENGL_PLATFORM={env}")
        os.environ["PYOPENGL_PLATFORM"] = requested
        return requested
    if env:
        if env not in BACKENDS:
            raise RenderBackendError(f"PYOPENGL_PLATFORM={env!r} is not supported here; use egl or osmesa")
        return env
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    errors = []
    for cand in BACKENDS:
        proc = subprocess.run([sys.executable, "-c", _PROBE, cand, root], capture_output=True, text=True,
                              timeout=120)
        if proc.returncode == 0:
            os.environ["PYOPENGL_PLATFORM"] = cand
            return cand
        errors.append(f"{cand}: {proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else proc.returncode}")
    raise RenderBackendError(INSTALL_HINT + " (" + "; ".join(errors) + ")")


#: the variable that picks one EGL device (its index among the machine's), e.g. one GPU of several
EGL_DEVICE_VAR = "MCDP_EGL_DEVICE"


def egl_device(n_devices: int | None = None) -> int | None:
    """The EGL device index `EGL_DEVICE_VAR` asks for (None: unset, try every device); ConfigError naming the
    variable when it is not an integer >= 0, or (given `n_devices`) not below the machine's device count."""
    from corelib.configlib import env_int

    hi = 1 << 16 if n_devices is None else n_devices - 1
    hint = f"the machine's EGL devices are 0 to {n_devices - 1}" if n_devices else "an EGL device index"
    if n_devices == 0 and os.environ.get(EGL_DEVICE_VAR, "").strip():
        raise RenderBackendError(f"environment variable {EGL_DEVICE_VAR} is set but this machine has no EGL device; "
                                 f"unset it, or set PYOPENGL_PLATFORM=osmesa")
    return env_int(EGL_DEVICE_VAR, None, 0, hi, hint)


# ----------------------------------------------------------------------------- contexts

class _EGLContext:
    def __init__(self, width: int, height: int) -> None:
        from OpenGL import EGL
        from OpenGL.EGL.EXT.device_base import egl_get_devices
        from OpenGL.EGL.EXT.platform_base import eglGetPlatformDisplayEXT
        from OpenGL.raw.EGL.EXT.platform_device import EGL_PLATFORM_DEVICE_EXT

        self.EGL = EGL
        devices = egl_get_devices()
        want = egl_device(len(devices))
        order = [want] if want is not None else list(range(len(devices)))
        last_err: Exception | None = None
        for idx in order:
            try:
                disp = eglGetPlatformDisplayEXT(EGL_PLATFORM_DEVICE_EXT, devices[idx], None)
                major, minor = EGL.EGLint(), EGL.EGLint()
                if not EGL.eglInitialize(disp, ctypes.pointer(major), ctypes.pointer(minor)):
                    continue
                attribs = [EGL.EGL_SURFACE_TYPE, EGL.EGL_PBUFFER_BIT, EGL.EGL_RENDERABLE_TYPE, EGL.EGL_OPENGL_BIT,
                           EGL.EGL_NONE]
                cfg, n = EGL.EGLConfig(), EGL.EGLint()
                EGL.eglChooseConfig(disp, (EGL.EGLint * len(attribs))(*attribs), ctypes.pointer(cfg), 1,
                                    ctypes.pointer(n))
                if n.value < 1:
                    continue
                EGL.eglBindAPI(EGL.EGL_OPENGL_API)
                ca = [EGL.EGL_CONTEXT_MAJOR_VERSION, 3, EGL.EGL_CONTEXT_MINOR_VERSION, 3,
                      EGL.EGL_CONTEXT_OPENGL_PROFILE_MASK, EGL.EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT, EGL.EGL_NONE]
                ctx = EGL.eglCreateContext(disp, cfg, EGL.EGL_NO_CONTEXT, (EGL.EGLint * len(ca))(*ca))
                if not ctx:
                    continue
                if not EGL.eglMakeCurrent(disp, EGL.EGL_NO_SURFACE, EGL.EGL_NO_SURFACE, ctx):
                    continue
                self.display, self.context = disp, ctx
                return
            except Exception as exc:  # try the next device
                last_err = exc
        raise RenderBackendError(f"EGL: no device gave an OpenGL 3.3 core context ({last_err}); " + INSTALL_HINT)

    def make_current(self) -> None:
        EGL = self.EGL
        EGL.eglMakeCurrent(self.display, EGL.EGL_NO_SURFACE, EGL.EGL_NO_SURFACE, self.context)

    def release(self) -> None:
        # eglTerminate would tear down the display shared by every context of the process
        # (it breaks other live renderers), so only the context is destroyed.
        EGL = self.EGL
        EGL.eglMakeCurrent(self.display, EGL.EGL_NO_SURFACE, EGL.EGL_NO_SURFACE, EGL.EGL_NO_CONTEXT)
        EGL.eglDestroyContext(self.display, self.context)


class _OSMesaContext:
    def __init__(self, width: int, height: int) -> None:
        from OpenGL import GL, osmesa

        self.osmesa = osmesa
        attrs = [osmesa.OSMESA_FORMAT, osmesa.OSMESA_RGBA, osmesa.OSMESA_DEPTH_BITS, 24,
                 osmesa.OSMESA_PROFILE, osmesa.OSMESA_CORE_PROFILE,
                 osmesa.OSMESA_CONTEXT_MAJOR_VERSION, 3, osmesa.OSMESA_CONTEXT_MINOR_VERSION, 3, 0]
        self.context = osmesa.OSMesaCreateContextAttribs((ctypes.c_int * len(attrs))(*attrs), None)
        if not self.context:
            raise RenderBackendError("OSMesa: could not create an OpenGL 3.3 core context; " + INSTALL_HINT)
        # we render into our own framebuffer object; this buffer only makes the context current
        self._buf = (ctypes.c_ubyte * (16 * 16 * 4))()
        self._GL = GL
        self.make_current()

    def make_current(self) -> None:
        if not self.osmesa.OSMesaMakeCurrent(self.context, self._buf, self._GL.GL_UNSIGNED_BYTE, 16, 16):
            raise RenderBackendError("OSMesa: OSMesaMakeCurrent failed")

    def release(self) -> None:
        self.osmesa.OSMesaDestroyContext(self.context)


def create_context(platform: str, width: int, height: int):
    """An off-screen OpenGL context of `platform` (``egl`` | ``osmesa``) with a `width` x `height` surface."""
    if platform == "egl":
        return _EGLContext(width, height)
    if platform == "osmesa":
        return _OSMesaContext(width, height)
    raise RenderBackendError(f"unknown OpenGL platform {platform!r}")
