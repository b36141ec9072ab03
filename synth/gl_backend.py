"""Off-screen OpenGL renderer (EGL, OSMesa fallback): RGB, exact z-depth and the ego mask.

With `synth.gl_context` (EGL / OSMesa contexts), `synth.shaders` (GLSL) and `synth.gl_objects` (buffers,
textures, framebuffers, programs), the only code that touches OpenGL. It draws a `scenes.model.Scene` seen by
one pinhole camera at a time and returns, for the stored image size (the renderer's own, or the
camera's ``size`` when cameras differ: one framebuffer per size):

* ``rgb``   (H, W, 3) uint8 sRGB (exposure gain and white balance applied);
* ``depth`` (H, W) float32 z-depth in metres at each pixel centre, 0 where no surface;
* ``ego``   (H, W) bool, True where the ego body is the nearest surface;
* with ``labels=True``: ``instance`` (H, W) int32, the object id of the nearest surface (`scenes.labels`;
  0 = stuff, the ego body or no surface), and ``layer`` (H, W) int32, its material layer (-1 = no surface).

Why not pyrender: the depth map is written by the fragment shader as the camera-frame
z interpolated at the pixel centre into a float32 target, so it is exact to float
precision (pyrender reads a 24-bit depth buffer, quantised as z^2 / (znear 2^24), and
its EGL path resolves depth from an MSAA sample ~3/8 px off the centre); rows are
flipped once here so row 0 is the top; K maps straight to the projection matrix.

The depth test compares linear depth, ``gl_FragDepth = z / zfar`` in a float32 buffer: its
resolution is relative (about 6e-8 z at every distance), so the near plane can sit 1 cm from
the camera (inside the roof the side cameras look down on) without losing resolution far away.
A hyperbolic depth buffer with znear = 1 cm would resolve only ~1.5 m at 400 m
(dz = 2^-24 z^2 / znear), and reversed z needs glClipControl, which PyOpenGL does not find on
OSMesa.

Back end choice: ``PYOPENGL_PLATFORM`` is honoured when set; otherwise EGL is probed
(in a subprocess, because PyOpenGL fixes its platform at import) and OSMesa is the
fallback. Example::

    r = Renderer(320, 192)          # picks EGL or OSMesa
    r.load_scene(scene, ego_mesh)
    out = r.render(K, T_world_cam, frame=0, light=light, gain=(1, 1, 1))
    out = r.render(K_back, T_world_back, frame=0, light=light, size=(480, 192))  # a camera of its own size
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scenes.model import Mesh, Scene

from synth.camera import gl_projection, pinhole_inverse
from synth.gl_context import RenderBackendError, create_context, select_backend
from synth.gl_objects import GpuMesh, compile_program, main_framebuffer, shadow_target, srgb_texture_array
from synth.shaders import FS_MAIN, FS_SHADOW, FS_SKY, VS_MAIN, VS_SHADOW, VS_SKY

__all__ = ["LightState", "RenderBackendError", "Renderer", "projection_from_K", "select_backend"]


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


#: OpenGL clip matrix for an OpenCV camera with intrinsics K: the camera table's pinhole row (`synth.camera`)
projection_from_K = gl_projection


@dataclass(frozen=True)
class _EgoLive:
    origin_ego: np.ndarray  # (3,) the cube's centre, ego frame (m)
    size_px: int
    matte_layer: float
    box_centre: np.ndarray  # (3,) ego frame (m)
    box_half: np.ndarray    # (3,) half extents (m)


def _cube_faces() -> np.ndarray:
    """(6, 3, 3) R_world_face of the live ego's cube: OpenCV cameras looking along world +x, -x, +y, -y, +z, -z
    (the order `synth.shaders` picks a face by the major axis of a direction)."""
    out = []
    for f, down in [((1, 0, 0), (0, 0, -1)), ((-1, 0, 0), (0, 0, -1)), ((0, 1, 0), (0, 0, -1)),
                    ((0, -1, 0), (0, 0, -1)), ((0, 0, 1), (1, 0, 0)), ((0, 0, -1), (1, 0, 0))]:
        f, down = np.array(f, np.float64), np.array(down, np.float64)
        out.append(np.column_stack([np.cross(down, f), down, f]))  # x right = y down x z forward
    return np.stack(out)


_ENV_R_WORLD_FACE = _cube_faces()


class Renderer:
    """One OpenGL context and a framebuffer of its image size (one more per other size asked of `render`);
    renders scenes camera by camera.

    Not thread-safe; use one per process (create it inside the worker process).
    """

    def __init__(self, width: int, height: int, backend: str = "auto", znear: float = 0.01,
                 zfar: float = 400.0, shadow_size: int = 2048, shadow_extent_m: float = 90.0) -> None:
        self.platform = select_backend(backend)
        self.width, self.height = int(width), int(height)
        self.znear, self.zfar = float(znear), float(zfar)
        self.shadow_size, self.shadow_extent = int(shadow_size), float(shadow_extent_m)
        self._ctx = create_context(self.platform, self.width, self.height)
        from OpenGL import GL

        self.GL = GL
        self.gl_renderer = GL.glGetString(GL.GL_RENDERER).decode()
        self._prog_main = self._program(VS_MAIN, FS_MAIN)
        self._prog_shadow = self._program(VS_SHADOW, FS_SHADOW)
        self._prog_sky = self._program(VS_SKY, FS_SKY)
        self._empty_vao = GL.glGenVertexArrays(1)
        self._make_framebuffers()
        self._static: GpuMesh | None = None
        self._movers: list[GpuMesh] = []
        self._ego: GpuMesh | None = None
        self._tex = None
        self._scene: Scene | None = None
        self._shadow_frame: int | None = None
        self._light_vp = np.eye(4)
        self._uniform_cache: dict[tuple[int, str], int] = {}
        self._ego_live: _EgoLive | None = None  # None: the ego body shaded like the world (static)
        self._env_tex = None
        self._env_frame: float | None = None

    # -- GL plumbing
    def _program(self, vs: str, fs: str) -> int:
        return compile_program(self.GL, vs, fs, self.gl_renderer)

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

    def _main_framebuffer(self, W: int, H: int) -> int:
        """The framebuffer of image size W x H (RGBA8 colour, RGBA32F depth value + ego flag + object id + material
        layer, float32 z), made
        on first use and kept."""
        fbo = self._fbos.get((W, H))
        if fbo is not None:
            return fbo
        fbo = main_framebuffer(self.GL, W, H)
        self._fbos[(W, H)] = fbo
        return fbo

    def _make_framebuffers(self) -> None:
        self._fbos: dict[tuple[int, int], int] = {}
        self._main_framebuffer(self.width, self.height)
        self._shadow_tex, self._shadow_fbo = shadow_target(self.GL, self.shadow_size)  # shadow map

    # -- scene
    def load_scene(self, scene: Scene, ego_mesh: Mesh | None) -> None:
        """Upload a scene's meshes and textures (replaces the previous scene)."""
        GL = self.GL
        self._ctx.make_current()
        self._free_scene()
        self._scene = scene
        self._static = GpuMesh(GL, scene.static)
        self._movers = [GpuMesh(GL, m.mesh) for m in scene.movers]
        self._ego = GpuMesh(GL, ego_mesh) if ego_mesh is not None else None
        self._tex = srgb_texture_array(GL, None, np.ascontiguousarray(scene.textures), tiled=True)
        self._shadow_frame = None
        self._ego_live, self._env_frame = None, None

    def set_ego_appearance(self, live: bool, matte_layer: int = -1, origin_ego=(0.8, 0.0, 1.6),
                           size_px: int = 64, box_ego=((-0.33, -0.93, 0.0), (3.6, 0.93, 1.48))) -> None:
        """``live``: from now until the next `load_scene`, the ego body's paint and glass are a clear coat
        that reflects the world (`synth.config.EgoConfig`): per frame time, the scene without the ego is
        rendered into six 90 deg cube faces of ``size_px`` px from ``origin_ego`` (ego frame, metres) and each
        ego fragment mixes in the face's colour along its mirrored view ray (Schlick's Fresnel) and the sun's
        highlight. ``box_ego``: the body's (min, max) corners, ego frame: its reflection normal leans half-way
        towards the normal of the ellipsoid in that box (a real body's panels are curved, so they mirror the
        horizon band where the moving world is, not only the sky above a flat roof).
        ``matte_layer``: the texture layer that keeps its diffuse look (the tyres). Only the RGB of
        ego pixels changes; depth, the ego flag, ids and layers are what a static render writes."""
        lo, hi = np.asarray(box_ego, np.float64)
        self._ego_live = _EgoLive(np.asarray(origin_ego, np.float64), int(size_px), float(matte_layer),
                                  (lo + hi) / 2, (hi - lo) / 2) if live else None
        self._env_frame = None

    def _render_env(self, frame: float, light: LightState) -> None:
        """The live ego's cube (`set_ego_appearance`): this frame's world (sky, static, movers; no ego) seen
        from the ego's `origin_ego`, unit gain, uploaded as an sRGB texture array of six faces, rows top first."""
        GL, live = self.GL, self._ego_live
        S = live.size_px
        T_world_ego = self._scene.ego_pose_at(frame)
        origin = T_world_ego[:3, :3] @ live.origin_ego + T_world_ego[:3, 3]
        K = np.array([[S / 2, 0.0, S / 2], [0.0, S / 2, S / 2], [0.0, 0.0, 1.0]])  # 90 deg
        faces = np.empty((6, S, S, 3), np.uint8)
        ego, self._ego, self._ego_live, self._env_frame = self._ego, None, None, frame  # no ego, no recursion
        try:
            for i, R in enumerate(_ENV_R_WORLD_FACE):
                T = np.eye(4)
                T[:3, :3], T[:3, 3] = R, origin
                faces[i] = self.render(K, T, frame, light, size=(S, S))["rgb"]
        finally:
            self._ego, self._ego_live = ego, live
        self._env_tex = srgb_texture_array(GL, self._env_tex, faces, tiled=False, unit=GL.GL_TEXTURE2)

    def _free_scene(self) -> None:
        for m in ([self._static, self._ego] + self._movers):
            if m is not None:
                m.delete()
        if self._tex is not None:
            self.GL.glDeleteTextures(1, [self._tex])
        self._static, self._ego, self._movers, self._tex = None, None, [], None

    def _object_poses(self, frame: float) -> list[np.ndarray]:
        return self._scene.mover_poses_at(frame)

    def _render_shadow(self, frame: int, light: LightState) -> None:
        GL = self.GL
        center = self._scene.ego_pose_at(frame)[:3, 3].copy()
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
            self._set_mat4(self._prog_shadow, "u_light_mvp", self._light_vp @ self._scene.ego_pose_at(frame))
            self._ego.draw()
        self._shadow_frame = frame

    def render(self, K: np.ndarray, T_world_cam: np.ndarray, frame: float, light: LightState,
               gain=(1.0, 1.0, 1.0), size: tuple[int, int] | None = None,
               labels: bool = False) -> dict[str, np.ndarray]:
        """Render one camera at one frame; see the module docstring for the outputs. ``frame`` is a continuous
        frame index (time ``frame / fps``): the movers and the ego body are posed at that time
        (`scenes.timeline`; at an integer, the frame's stored poses). ``size`` (width, height):
        the camera's image size, K's pixels (None: the renderer's); ``labels``: read back object ids and layers
        too. Mover k draws as object `Scene.mover_instance(k)`."""
        if self._scene is None:
            raise RuntimeError("Renderer.render called before load_scene")
        GL = self.GL
        self._ctx.make_current()
        if light.shadows and self._shadow_frame != frame:
            self._render_shadow(frame, light)
        if self._ego_live is not None and self._env_frame != frame:
            self._render_env(frame, light)
        W, H = (self.width, self.height) if size is None else (int(size[0]), int(size[1]))
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, self._main_framebuffer(W, H))
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
        self._set_mat3(ps, "u_K_inv", pinhole_inverse(K))
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
        GL.glUniform1f(self._loc(pm, "u_zfar"), self.zfar)
        GL.glUniform1i(self._loc(pm, "u_use_shadow"), 1 if light.shadows else 0)
        GL.glActiveTexture(GL.GL_TEXTURE0)
        GL.glBindTexture(GL.GL_TEXTURE_2D_ARRAY, self._tex)
        GL.glUniform1i(self._loc(pm, "u_tex"), 0)
        GL.glActiveTexture(GL.GL_TEXTURE1)
        GL.glBindTexture(GL.GL_TEXTURE_2D, self._shadow_tex)
        GL.glUniform1i(self._loc(pm, "u_shadow"), 1)
        GL.glUniform1i(self._loc(pm, "u_ego_live"), 0 if self._ego_live is None else 1)
        if self._ego_live is not None:
            GL.glActiveTexture(GL.GL_TEXTURE2)
            GL.glBindTexture(GL.GL_TEXTURE_2D_ARRAY, self._env_tex)
            GL.glUniform1i(self._loc(pm, "u_env"), 2)
            self.GL.glUniformMatrix3fv(self._loc(pm, "u_env_R"), 6, GL.GL_FALSE,  # R_world_face: its transpose
                                       np.ascontiguousarray(_ENV_R_WORLD_FACE, np.float32))
            self._set_vec3(pm, "u_cam_pos", T_world_cam[:3, 3])
            GL.glUniform1f(self._loc(pm, "u_ego_matte_layer"), self._ego_live.matte_layer)
            self._set_vec3(pm, "u_ego_centre", self._ego_live.box_centre)
            self._set_vec3(pm, "u_ego_half", self._ego_live.box_half)

        def draw(gm: GpuMesh, T_world_obj: np.ndarray, is_ego: float, instance: float) -> None:
            self._set_mat4(pm, "u_model", T_world_obj)
            self._set_mat4(pm, "u_modelview", T_cam_world @ T_world_obj)
            GL.glUniform1f(self._loc(pm, "u_is_ego"), is_ego)
            GL.glUniform1f(self._loc(pm, "u_instance"), instance)
            gm.draw()

        draw(self._static, np.eye(4), 0.0, -1.0)
        for k, (gm, T) in enumerate(zip(self._movers, self._object_poses(frame))):
            draw(gm, T, 0.0, float(self._scene.mover_instance(k)))
        if self._ego is not None:
            draw(self._ego, self._scene.ego_pose_at(frame), 1.0, 0.0)
        # read back (GL rows are bottom-up)
        GL.glPixelStorei(GL.GL_PACK_ALIGNMENT, 1)
        GL.glReadBuffer(GL.GL_COLOR_ATTACHMENT0)
        rgba = np.empty((H, W, 4), np.uint8)
        GL.glReadPixels(0, 0, W, H, GL.GL_RGBA, GL.GL_UNSIGNED_BYTE, rgba)
        rgb = rgba[::-1, :, :3].copy()
        GL.glReadBuffer(GL.GL_COLOR_ATTACHMENT1)
        dv = np.empty((H, W, 4 if labels else 2), np.float32)
        GL.glReadPixels(0, 0, W, H, GL.GL_RGBA if labels else GL.GL_RG, GL.GL_FLOAT, dv)
        dv = dv[::-1]
        depth = np.ascontiguousarray(dv[..., 0])
        ego = dv[..., 1] > 0.5
        out = {"rgb": rgb, "depth": depth, "ego": ego}
        if labels:
            out["instance"] = np.rint(dv[..., 2]).astype(np.int32)
            out["layer"] = np.rint(dv[..., 3]).astype(np.int32)
        return out

    def close(self) -> None:
        """Free GL objects and the context (never the process-wide EGL display)."""
        if self._ctx is None:
            return
        self._ctx.make_current()
        self._free_scene()
        if self._env_tex is not None:
            self.GL.glDeleteTextures(1, [self._env_tex])
            self._env_tex = None
        self._ctx.release()
        self._ctx = None

    def __enter__(self) -> "Renderer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
