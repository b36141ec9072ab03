"""Off-screen OpenGL renderer (EGL, OSMesa fallback): RGB, exact z-depth and the ego mask.

This is the only module that imports OpenGL. It draws a `scenes.model.Scene` seen by
one pinhole camera at a time and returns, for the stored image size:

* ``rgb``   (H, W, 3) uint8 sRGB (exposure gain and white balance applied);
* ``depth`` (H, W) float32 z-depth in metres at each pixel centre, 0 where no surface;
* ``ego``   (H, W) bool, True where the ego body is the nearest surface.

Why not pyrender: the depth map is written by the fragment shader as the camera-frame
z interpolated at the pixel centre into a float32 target, so it is exact to float
precision (pyrender reads a 24-bit depth buffer, quantised as z^2 / (znear 2^24), and
its EGL path resolves depth from an MSAA sample ~3/8 px off the centre); rows are
flipped once here so row 0 is the top; K maps straight to the projection matrix.

Back end choice: ``PYOPENGL_PLATFORM`` is honoured when set; otherwise EGL is probed
(in a subprocess, because PyOpenGL fixes its platform at import) and OSMesa is the
fallback. Example::

    r = Renderer(320, 192)          # picks EGL or OSMesa
    r.load_scene(scene, ego_mesh)
    out = r.render(K, T_world_cam, frame=0, light=light, gain=(1, 1, 1))
"""
from __future__ import annotations

import ctypes
import os
import subprocess
import sys
from dataclasses import dataclass

import numpy as np

from scenes.model import Mesh, Scene

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
from synth.gl_backend import _create_context
ctx = _create_context(sys.argv[1], 16, 16)
from OpenGL import GL
print(GL.glGetString(GL.GL_RENDERER).decode())
"""


def select_backend(requested: str = "auto") -> str:
    """Pick the OpenGL platform: `requested`, else $PYOPENGL_PLATFORM, else EGL, else OSMesa.

    Sets $PYOPENGL_PLATFORM so worker processes inherit the choice.
    """
    env = os.environ.get("PYOPENGL_PLATFORM", "").strip().lower()
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


# ----------------------------------------------------------------------------- contexts

class _EGLContext:
    def __init__(self, width: int, height: int) -> None:
        from OpenGL import EGL
        from OpenGL.EGL.EXT.device_base import egl_get_devices
        from OpenGL.EGL.EXT.platform_base import eglGetPlatformDisplayEXT
        from OpenGL.raw.EGL.EXT.platform_device import EGL_PLATFORM_DEVICE_EXT

        self.EGL = EGL
        devices = egl_get_devices()
        want = os.environ.get("MCDP_EGL_DEVICE")
        order = [int(want)] if want is not None else list(range(len(devices)))
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


def _create_context(platform: str, width: int, height: int):
    if platform == "egl":
        return _EGLContext(width, height)
    if platform == "osmesa":
        return _OSMesaContext(width, height)
    raise RenderBackendError(f"unknown OpenGL platform {platform!r}")


# ----------------------------------------------------------------------------- shaders

_GLSL_TO_SRGB = """
vec3 to_srgb(vec3 c) {
    c = clamp(c, 0.0, 1.0);
    return mix(c * 12.92, 1.055 * pow(c, vec3(1.0 / 2.4)) - 0.055, step(vec3(0.0031308), c));
}
"""

_VS_MAIN = """
#version 330 core
layout(location=0) in vec3 a_pos;
layout(location=1) in vec3 a_nrm;
layout(location=2) in vec2 a_uv;
layout(location=3) in float a_layer;
layout(location=4) in vec3 a_tint;
uniform mat4 u_model;      // world <- object
uniform mat4 u_modelview;  // camera (OpenCV) <- object, composed in float64
uniform mat4 u_proj;
uniform mat4 u_light_vp;   // light clip <- world
out vec3 v_nrm_w;
out vec2 v_uv;
flat out float v_layer;
out vec3 v_tint;
out float v_zcam;
out float v_dist;
out vec4 v_light;
void main() {
    vec4 pc = u_modelview * vec4(a_pos, 1.0);
    vec4 pw = u_model * vec4(a_pos, 1.0);
    v_zcam = pc.z;
    v_dist = length(pc.xyz);
    v_nrm_w = mat3(u_model) * a_nrm;
    v_uv = a_uv;
    v_layer = a_layer;
    v_tint = a_tint;
    v_light = u_light_vp * pw;
    gl_Position = u_proj * pc;
}
"""

_FS_MAIN = """
#version 330 core
in vec3 v_nrm_w;
in vec2 v_uv;
flat in float v_layer;
in vec3 v_tint;
in float v_zcam;
in float v_dist;
in vec4 v_light;
uniform sampler2DArray u_tex;
uniform sampler2DShadow u_shadow;
uniform int u_use_shadow;
uniform vec3 u_sun_dir;      // world, towards the sun
uniform vec3 u_sun_rgb;      // linear radiance scale
uniform vec3 u_ambient_rgb;
uniform vec3 u_gain;         // exposure * white balance
uniform vec3 u_fog_rgb;
uniform float u_fog_dist;
uniform float u_is_ego;
layout(location=0) out vec4 o_color;
layout(location=1) out vec2 o_depth;
%(to_srgb)svoid main() {
    vec3 n = normalize(v_nrm_w);
    if (!gl_FrontFacing) n = -n;
    vec3 albedo = texture(u_tex, vec3(v_uv, v_layer)).rgb * v_tint;
    float ndl = max(dot(n, u_sun_dir), 0.0);
    float lit = 1.0;
    if (u_use_shadow == 1 && ndl > 0.0) {
        vec3 p = v_light.xyz / v_light.w * 0.5 + 0.5;
        if (p.x > 0.0 && p.x < 1.0 && p.y > 0.0 && p.y < 1.0 && p.z < 1.0) {
            float bias = 0.0015 + 0.004 * (1.0 - ndl);
            lit = texture(u_shadow, vec3(p.xy, p.z - bias));
        }
    }
    float sky_vis = 0.75 + 0.25 * n.z;
    vec3 c = albedo * (u_ambient_rgb * sky_vis + u_sun_rgb * ndl * lit);
    float f = 1.0 - exp(-v_dist / u_fog_dist);
    c = mix(c, u_fog_rgb, f);
    o_color = vec4(to_srgb(c * u_gain), 1.0);
    o_depth = vec2(v_zcam, u_is_ego);
}
"""

_FS_MAIN = _FS_MAIN % {"to_srgb": _GLSL_TO_SRGB}

_VS_SHADOW = """
#version 330 core
layout(location=0) in vec3 a_pos;
uniform mat4 u_light_mvp;
void main() { gl_Position = u_light_mvp * vec4(a_pos, 1.0); }
"""

_FS_SHADOW = """
#version 330 core
void main() { }
"""

_VS_SKY = """
#version 330 core
const vec2 P[3] = vec2[3](vec2(-1.0, -1.0), vec2(3.0, -1.0), vec2(-1.0, 3.0));
void main() { gl_Position = vec4(P[gl_VertexID], 1.0, 1.0); }
"""

_FS_SKY = """
#version 330 core
uniform mat3 u_R_world_cam;
uniform mat3 u_K_inv;
uniform float u_height;
uniform vec3 u_zenith_rgb;
uniform vec3 u_horizon_rgb;
uniform vec3 u_sun_dir;
uniform vec3 u_sun_rgb;
uniform vec3 u_gain;
layout(location=0) out vec4 o_color;
layout(location=1) out vec2 o_depth;
%(to_srgb)svoid main() {
    vec2 uv = vec2(gl_FragCoord.x, u_height - gl_FragCoord.y);   // OpenCV pixel coordinates
    vec3 d = normalize(u_R_world_cam * (u_K_inv * vec3(uv, 1.0)));
    float t = clamp(d.z, 0.0, 1.0);
    vec3 c = mix(u_horizon_rgb, u_zenith_rgb, pow(t, 0.6));
    if (d.z < 0.0) c = u_horizon_rgb * 0.8;
    float s = max(dot(d, u_sun_dir), 0.0);
    c += u_sun_rgb * (0.25 * pow(s, 64.0) + 2.0 * pow(s, 2000.0));
    o_color = vec4(to_srgb(c * u_gain), 1.0);
    o_depth = vec2(0.0, 0.0);
}
"""


_FS_SKY = _FS_SKY % {"to_srgb": _GLSL_TO_SRGB}


# ----------------------------------------------------------------------------- renderer

@dataclass(frozen=True)
class LightState:
    """Lighting of one frame, linear RGB. `sun_dir` is a unit vector in the world frame towards the sun."""

    sun_dir: tuple[float, float, float]
    sun_rgb: tuple[float, float, float]
    ambient_rgb: tuple[float, float, float]
    zenith_rgb: tuple[float, float, float]
    horizon_rgb: tuple[float, float, float]
    fog_dist_m: float = 900.0
    shadows: bool = True


def projection_from_K(K: np.ndarray, width: int, height: int, znear: float, zfar: float) -> np.ndarray:
    """OpenGL clip matrix for an OpenCV camera (x right, y down, z forward) with intrinsics K.

    Maps pixel u (pixel centres at +0.5) to window x = u and v to window y = H - v.
    """
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    P = np.zeros((4, 4))
    P[0, 0] = 2 * fx / width
    P[0, 1] = 2 * K[0, 1] / width
    P[0, 2] = 2 * cx / width - 1
    P[1, 1] = -2 * fy / height
    P[1, 2] = 1 - 2 * cy / height
    P[2, 2] = (zfar + znear) / (zfar - znear)
    P[2, 3] = -2 * zfar * znear / (zfar - znear)
    P[3, 2] = 1.0
    return P


class _GpuMesh:
    def __init__(self, GL, mesh: Mesh) -> None:
        self.GL = GL
        data = np.concatenate([mesh.positions, mesh.normals, mesh.uvs, mesh.layers[:, None].astype(np.float32),
                               mesh.tints], axis=1).astype(np.float32)
        data = np.ascontiguousarray(data)
        self.vao = GL.glGenVertexArrays(1)
        GL.glBindVertexArray(self.vao)
        self.vbo = GL.glGenBuffers(1)
        GL.glBindBuffer(GL.GL_ARRAY_BUFFER, self.vbo)
        GL.glBufferData(GL.GL_ARRAY_BUFFER, data.nbytes, data, GL.GL_STATIC_DRAW)
        stride = 12 * 4
        for loc, (size, off) in enumerate([(3, 0), (3, 3), (2, 6), (1, 8), (3, 9)]):
            GL.glEnableVertexAttribArray(loc)
            GL.glVertexAttribPointer(loc, size, GL.GL_FLOAT, GL.GL_FALSE, stride, ctypes.c_void_p(off * 4))
        self.ebo = GL.glGenBuffers(1)
        GL.glBindBuffer(GL.GL_ELEMENT_ARRAY_BUFFER, self.ebo)
        idx = np.ascontiguousarray(mesh.indices.reshape(-1), np.uint32)
        GL.glBufferData(GL.GL_ELEMENT_ARRAY_BUFFER, idx.nbytes, idx, GL.GL_STATIC_DRAW)
        self.count = int(idx.size)
        GL.glBindVertexArray(0)

    def draw(self) -> None:
        if self.count:
            self.GL.glBindVertexArray(self.vao)
            self.GL.glDrawElements(self.GL.GL_TRIANGLES, self.count, self.GL.GL_UNSIGNED_INT, None)

    def delete(self) -> None:
        GL = self.GL
        GL.glDeleteBuffers(2, [self.vbo, self.ebo])
        GL.glDeleteVertexArrays(1, [self.vao])


class Renderer:
    """One OpenGL context and framebuffer of a fixed image size; renders scenes camera by camera.

    Not thread-safe; use one per process (create it inside the worker process).
    """

    def __init__(self, width: int, height: int, backend: str = "auto", znear: float = 0.5,
                 zfar: float = 400.0, shadow_size: int = 2048, shadow_extent_m: float = 90.0) -> None:
        self.platform = select_backend(backend)
        self.width, self.height = int(width), int(height)
        self.znear, self.zfar = float(znear), float(zfar)
        self.shadow_size, self.shadow_extent = int(shadow_size), float(shadow_extent_m)
        self._ctx = _create_context(self.platform, self.width, self.height)
        from OpenGL import GL

        self.GL = GL
        self.gl_renderer = GL.glGetString(GL.GL_RENDERER).decode()
        self._prog_main = self._program(_VS_MAIN, _FS_MAIN)
        self._prog_shadow = self._program(_VS_SHADOW, _FS_SHADOW)
        self._prog_sky = self._program(_VS_SKY, _FS_SKY)
        self._empty_vao = GL.glGenVertexArrays(1)
        self._make_framebuffers()
        self._static: _GpuMesh | None = None
        self._movers: list[_GpuMesh] = []
        self._ego: _GpuMesh | None = None
        self._tex = None
        self._scene: Scene | None = None
        self._shadow_frame: int | None = None
        self._light_vp = np.eye(4)
        self._uniform_cache: dict[tuple[int, str], int] = {}

    # -- GL plumbing
    def _program(self, vs: str, fs: str) -> int:
        GL = self.GL
        from OpenGL.GL import shaders

        try:
            return shaders.compileProgram(shaders.compileShader(vs, GL.GL_VERTEX_SHADER),
                                          shaders.compileShader(fs, GL.GL_FRAGMENT_SHADER), validate=False)
        except Exception as exc:  # shader errors are bugs, but say where
            raise RenderBackendError(f"shader compilation failed on {self.gl_renderer}: {exc}") from exc

    def _loc(self, prog: int, name: str) -> int:
        key = (prog, name)
        if key not in self._uniform_cache:
            self._uniform_cache[key] = self.GL.glGetUniformLocation(prog, name)
        return self._uniform_cache[key]

    def _set_mat4(self, prog: int, name: str, M: np.ndarray) -> None:
        self.GL.glUniformMatrix4fv(self._loc(prog, name), 1, self.GL.GL_TRUE, np.ascontiguousarray(M, np.float32))

    def _set_mat3(self, prog: int, name: str, M: np.ndarray) -> None:
        self.GL.glUniformMatrix3fv(self._loc(prog, name), 1, self.GL.GL_TRUE, np.ascontiguousarray(M, np.float32))

    def _set_vec3(self, prog: int, name: str, v) -> None:
        self.GL.glUniform3f(self._loc(prog, name), *[float(x) for x in v])

    def _make_framebuffers(self) -> None:
        GL = self.GL
        W, H = self.width, self.height
        self._fbo = GL.glGenFramebuffers(1)
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, self._fbo)
        self._rb_color, self._rb_depthval, self._rb_z = GL.glGenRenderbuffers(3)
        GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, self._rb_color)
        GL.glRenderbufferStorage(GL.GL_RENDERBUFFER, GL.GL_RGBA8, W, H)
        GL.glFramebufferRenderbuffer(GL.GL_FRAMEBUFFER, GL.GL_COLOR_ATTACHMENT0, GL.GL_RENDERBUFFER, self._rb_color)
        GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, self._rb_depthval)
        GL.glRenderbufferStorage(GL.GL_RENDERBUFFER, GL.GL_RG32F, W, H)
        GL.glFramebufferRenderbuffer(GL.GL_FRAMEBUFFER, GL.GL_COLOR_ATTACHMENT1, GL.GL_RENDERBUFFER,
                                     self._rb_depthval)
        GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, self._rb_z)
        GL.glRenderbufferStorage(GL.GL_RENDERBUFFER, GL.GL_DEPTH_COMPONENT32F, W, H)
        GL.glFramebufferRenderbuffer(GL.GL_FRAMEBUFFER, GL.GL_DEPTH_ATTACHMENT, GL.GL_RENDERBUFFER, self._rb_z)
        GL.glDrawBuffers(2, [GL.GL_COLOR_ATTACHMENT0, GL.GL_COLOR_ATTACHMENT1])
        if GL.glCheckFramebufferStatus(GL.GL_FRAMEBUFFER) != GL.GL_FRAMEBUFFER_COMPLETE:
            raise RenderBackendError("main framebuffer incomplete")
        # shadow map
        S = self.shadow_size
        self._shadow_tex = GL.glGenTextures(1)
        GL.glBindTexture(GL.GL_TEXTURE_2D, self._shadow_tex)
        GL.glTexImage2D(GL.GL_TEXTURE_2D, 0, GL.GL_DEPTH_COMPONENT32F, S, S, 0, GL.GL_DEPTH_COMPONENT, GL.GL_FLOAT,
                        None)
        for p, v in [(GL.GL_TEXTURE_MIN_FILTER, GL.GL_LINEAR), (GL.GL_TEXTURE_MAG_FILTER, GL.GL_LINEAR),
                     (GL.GL_TEXTURE_WRAP_S, GL.GL_CLAMP_TO_EDGE), (GL.GL_TEXTURE_WRAP_T, GL.GL_CLAMP_TO_EDGE),
                     (GL.GL_TEXTURE_COMPARE_MODE, GL.GL_COMPARE_REF_TO_TEXTURE),
                     (GL.GL_TEXTURE_COMPARE_FUNC, GL.GL_LEQUAL)]:
            GL.glTexParameteri(GL.GL_TEXTURE_2D, p, v)
        self._shadow_fbo = GL.glGenFramebuffers(1)
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, self._shadow_fbo)
        GL.glFramebufferTexture2D(GL.GL_FRAMEBUFFER, GL.GL_DEPTH_ATTACHMENT, GL.GL_TEXTURE_2D, self._shadow_tex, 0)
        GL.glDrawBuffer(GL.GL_NONE)
        GL.glReadBuffer(GL.GL_NONE)
        if GL.glCheckFramebufferStatus(GL.GL_FRAMEBUFFER) != GL.GL_FRAMEBUFFER_COMPLETE:
            raise RenderBackendError("shadow framebuffer incomplete")

    # -- scene
    def load_scene(self, scene: Scene, ego_mesh: Mesh | None) -> None:
        """Upload a scene's meshes and textures (replaces the previous scene)."""
        GL = self.GL
        self._ctx.make_current()
        self._free_scene()
        self._scene = scene
        self._static = _GpuMesh(GL, scene.static)
        self._movers = [_GpuMesh(GL, m.mesh) for m in scene.movers]
        self._ego = _GpuMesh(GL, ego_mesh) if ego_mesh is not None else None
        tex = np.ascontiguousarray(scene.textures)
        L, S = tex.shape[0], tex.shape[1]
        self._tex = GL.glGenTextures(1)
        GL.glBindTexture(GL.GL_TEXTURE_2D_ARRAY, self._tex)
        GL.glPixelStorei(GL.GL_UNPACK_ALIGNMENT, 1)
        GL.glTexImage3D(GL.GL_TEXTURE_2D_ARRAY, 0, GL.GL_SRGB8, S, S, L, 0, GL.GL_RGB, GL.GL_UNSIGNED_BYTE, tex)
        GL.glGenerateMipmap(GL.GL_TEXTURE_2D_ARRAY)
        for p, v in [(GL.GL_TEXTURE_MIN_FILTER, GL.GL_LINEAR_MIPMAP_LINEAR), (GL.GL_TEXTURE_MAG_FILTER, GL.GL_LINEAR),
                     (GL.GL_TEXTURE_WRAP_S, GL.GL_REPEAT), (GL.GL_TEXTURE_WRAP_T, GL.GL_REPEAT)]:
            GL.glTexParameteri(GL.GL_TEXTURE_2D_ARRAY, p, v)
        self._shadow_frame = None

    def _free_scene(self) -> None:
        for m in ([self._static, self._ego] + self._movers):
            if m is not None:
                m.delete()
        if self._tex is not None:
            self.GL.glDeleteTextures(1, [self._tex])
        self._static, self._ego, self._movers, self._tex = None, None, [], None

    def _object_poses(self, frame: int) -> list[np.ndarray]:
        return [m.T_world_obj[frame] for m in self._scene.movers]

    def _render_shadow(self, frame: int, light: LightState) -> None:
        GL = self.GL
        center = self._scene.T_world_ego[frame][:3, 3].copy()
        center[2] = 0.0
        sun = np.asarray(light.sun_dir, np.float64)
        sun /= np.linalg.norm(sun)
        eye = center + sun * 300.0
        f = center - eye
        f /= np.linalg.norm(f)
        up = np.array([0.0, 0.0, 1.0]) if abs(f[2]) < 0.99 else np.array([1.0, 0.0, 0.0])
        r = np.cross(f, up)
        r /= np.linalg.norm(r)
        u = np.cross(r, f)
        V = np.eye(4)
        V[0, :3], V[1, :3], V[2, :3] = r, u, -f
        V[:3, 3] = -V[:3, :3] @ eye
        e, n, fa = self.shadow_extent, 1.0, 700.0
        P = np.diag([1 / e, 1 / e, -2 / (fa - n), 1.0])
        P[2, 3] = -(fa + n) / (fa - n)
        self._light_vp = P @ V
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, self._shadow_fbo)
        GL.glViewport(0, 0, self.shadow_size, self.shadow_size)
        GL.glClear(GL.GL_DEPTH_BUFFER_BIT)
        GL.glEnable(GL.GL_DEPTH_TEST)
        GL.glUseProgram(self._prog_shadow)
        self._set_mat4(self._prog_shadow, "u_light_mvp", self._light_vp)
        self._static.draw()
        for gm, T in zip(self._movers, self._object_poses(frame)):
            self._set_mat4(self._prog_shadow, "u_light_mvp", self._light_vp @ T)
            gm.draw()
        if self._ego is not None:
            self._set_mat4(self._prog_shadow, "u_light_mvp", self._light_vp @ self._scene.T_world_ego[frame])
            self._ego.draw()
        self._shadow_frame = frame

    def render(self, K: np.ndarray, T_world_cam: np.ndarray, frame: int, light: LightState,
               gain=(1.0, 1.0, 1.0)) -> dict[str, np.ndarray]:
        """Render one camera at one frame; see the module docstring for the outputs."""
        if self._scene is None:
            raise RuntimeError("Renderer.render called before load_scene")
        GL = self.GL
        self._ctx.make_current()
        if light.shadows and self._shadow_frame != frame:
            self._render_shadow(frame, light)
        W, H = self.width, self.height
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, self._fbo)
        GL.glViewport(0, 0, W, H)
        GL.glClearBufferfv(GL.GL_COLOR, 1, np.zeros(4, np.float32))
        GL.glClear(GL.GL_DEPTH_BUFFER_BIT)
        T_cam_world = np.linalg.inv(T_world_cam)
        sun = np.asarray(light.sun_dir, np.float64)
        sun = sun / np.linalg.norm(sun)
        # sky: full-screen triangle at the far plane, drawn without depth writes
        GL.glDisable(GL.GL_DEPTH_TEST)
        GL.glUseProgram(self._prog_sky)
        ps = self._prog_sky
        self._set_mat3(ps, "u_R_world_cam", T_world_cam[:3, :3])
        self._set_mat3(ps, "u_K_inv", np.linalg.inv(K))
        GL.glUniform1f(self._loc(ps, "u_height"), float(H))
        for name, val in [("u_zenith_rgb", light.zenith_rgb), ("u_horizon_rgb", light.horizon_rgb),
                          ("u_sun_dir", sun), ("u_sun_rgb", light.sun_rgb), ("u_gain", gain)]:
            self._set_vec3(ps, name, val)
        GL.glBindVertexArray(self._empty_vao)
        GL.glDrawArrays(GL.GL_TRIANGLES, 0, 3)
        # geometry
        GL.glEnable(GL.GL_DEPTH_TEST)
        GL.glDepthFunc(GL.GL_LESS)
        GL.glDisable(GL.GL_CULL_FACE)
        pm = self._prog_main
        GL.glUseProgram(pm)
        self._set_mat4(pm, "u_proj", projection_from_K(K, W, H, self.znear, self.zfar))
        self._set_mat4(pm, "u_light_vp", self._light_vp)
        for name, val in [("u_sun_dir", sun), ("u_sun_rgb", light.sun_rgb), ("u_ambient_rgb", light.ambient_rgb),
                          ("u_gain", gain), ("u_fog_rgb", light.horizon_rgb)]:
            self._set_vec3(pm, name, val)
        GL.glUniform1f(self._loc(pm, "u_fog_dist"), float(light.fog_dist_m))
        GL.glUniform1i(self._loc(pm, "u_use_shadow"), 1 if light.shadows else 0)
        GL.glActiveTexture(GL.GL_TEXTURE0)
        GL.glBindTexture(GL.GL_TEXTURE_2D_ARRAY, self._tex)
        GL.glUniform1i(self._loc(pm, "u_tex"), 0)
        GL.glActiveTexture(GL.GL_TEXTURE1)
        GL.glBindTexture(GL.GL_TEXTURE_2D, self._shadow_tex)
        GL.glUniform1i(self._loc(pm, "u_shadow"), 1)

        def draw(gm: _GpuMesh, T_world_obj: np.ndarray, is_ego: float) -> None:
            self._set_mat4(pm, "u_model", T_world_obj)
            self._set_mat4(pm, "u_modelview", T_cam_world @ T_world_obj)
            GL.glUniform1f(self._loc(pm, "u_is_ego"), is_ego)
            gm.draw()

        draw(self._static, np.eye(4), 0.0)
        for gm, T in zip(self._movers, self._object_poses(frame)):
            draw(gm, T, 0.0)
        if self._ego is not None:
            draw(self._ego, self._scene.T_world_ego[frame], 1.0)
        # read back (GL rows are bottom-up)
        GL.glPixelStorei(GL.GL_PACK_ALIGNMENT, 1)
        GL.glReadBuffer(GL.GL_COLOR_ATTACHMENT0)
        rgba = np.empty((H, W, 4), np.uint8)
        GL.glReadPixels(0, 0, W, H, GL.GL_RGBA, GL.GL_UNSIGNED_BYTE, rgba)
        rgb = rgba[::-1, :, :3].copy()
        GL.glReadBuffer(GL.GL_COLOR_ATTACHMENT1)
        dv = np.empty((H, W, 2), np.float32)
        GL.glReadPixels(0, 0, W, H, GL.GL_RG, GL.GL_FLOAT, dv)
        dv = dv[::-1]
        depth = np.ascontiguousarray(dv[..., 0])
        ego = dv[..., 1] > 0.5
        return {"rgb": rgb, "depth": depth, "ego": ego}

    def close(self) -> None:
        """Free GL objects and the context (never the process-wide EGL display)."""
        if self._ctx is None:
            return
        self._ctx.make_current()
        self._free_scene()
        self._ctx.release()
        self._ctx = None

    def __enter__(self) -> "Renderer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
