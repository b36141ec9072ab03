"""The renderer's OpenGL objects (`synth.gl_backend`): what it allocates and uploads, not how it draws.

* `GpuMesh`: a `scenes.model.Mesh` as a vertex array (position, normal, uv, layer, tint, instance);
* `compile_program`: a GLSL program from `synth.shaders`;
* `main_framebuffer`: the target of one image size (RGBA8 colour, RGBA32F depth value + ego flag + object id
  + material layer, float32 z);
* `shadow_target`: the shadow map's depth texture (compared, `sampler2DShadow`) and its framebuffer;
* `srgb_texture_array`: (L, S, S, 3) uint8 sRGB images as a texture array (the materials; the live ego's cube).

With `synth.gl_context`, `synth.shaders` and `synth.gl_backend`, the only code that touches OpenGL. Each
function takes the ``OpenGL.GL`` module of the current context.
"""
from __future__ import annotations

import ctypes

import numpy as np

from scenes.model import Mesh

from synth.gl_context import RenderBackendError

__all__ = ["GpuMesh", "compile_program", "main_framebuffer", "shadow_target", "srgb_texture_array"]


class GpuMesh:
    """A mesh's vertex array, vertex and index buffers; `draw` issues its triangles."""

    def __init__(self, GL, mesh: Mesh) -> None:
        self.GL = GL
        data = np.concatenate([mesh.positions, mesh.normals, mesh.uvs, mesh.layers[:, None].astype(np.float32),
                               mesh.tints, mesh.instances[:, None].astype(np.float32)], axis=1).astype(np.float32)
        data = np.ascontiguousarray(data)
        self.vao = GL.glGenVertexArrays(1)
        GL.glBindVertexArray(self.vao)
        self.vbo = GL.glGenBuffers(1)
        GL.glBindBuffer(GL.GL_ARRAY_BUFFER, self.vbo)
        GL.glBufferData(GL.GL_ARRAY_BUFFER, data.nbytes, data, GL.GL_STATIC_DRAW)
        stride = 13 * 4
        for loc, (size, off) in enumerate([(3, 0), (3, 3), (2, 6), (1, 8), (3, 9), (1, 12)]):
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


def compile_program(GL, vs: str, fs: str, gl_renderer: str) -> int:
    """The program of vertex shader `vs` and fragment shader `fs`; RenderBackendError names `gl_renderer`."""
    from OpenGL.GL import shaders

    try:
        return shaders.compileProgram(shaders.compileShader(vs, GL.GL_VERTEX_SHADER),
                                      shaders.compileShader(fs, GL.GL_FRAGMENT_SHADER), validate=False)
    except Exception as exc:  # shader errors are bugs, but say where
        raise RenderBackendError(f"shader compilation failed on {gl_renderer}: {exc}") from exc


def main_framebuffer(GL, W: int, H: int) -> int:
    """A new framebuffer of image size W x H, left bound: RGBA8 colour (attachment 0), RGBA32F depth value + ego
    flag + object id + material layer (attachment 1), float32 z, both colour attachments drawn."""
    fbo = GL.glGenFramebuffers(1)
    GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, fbo)
    rb_color, rb_depthval, rb_z = GL.glGenRenderbuffers(3)
    GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, rb_color)
    GL.glRenderbufferStorage(GL.GL_RENDERBUFFER, GL.GL_RGBA8, W, H)
    GL.glFramebufferRenderbuffer(GL.GL_FRAMEBUFFER, GL.GL_COLOR_ATTACHMENT0, GL.GL_RENDERBUFFER, rb_color)
    GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, rb_depthval)
    GL.glRenderbufferStorage(GL.GL_RENDERBUFFER, GL.GL_RGBA32F, W, H)
    GL.glFramebufferRenderbuffer(GL.GL_FRAMEBUFFER, GL.GL_COLOR_ATTACHMENT1, GL.GL_RENDERBUFFER, rb_depthval)
    GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, rb_z)
    GL.glRenderbufferStorage(GL.GL_RENDERBUFFER, GL.GL_DEPTH_COMPONENT32F, W, H)
    GL.glFramebufferRenderbuffer(GL.GL_FRAMEBUFFER, GL.GL_DEPTH_ATTACHMENT, GL.GL_RENDERBUFFER, rb_z)
    GL.glDrawBuffers(2, [GL.GL_COLOR_ATTACHMENT0, GL.GL_COLOR_ATTACHMENT1])
    if GL.glCheckFramebufferStatus(GL.GL_FRAMEBUFFER) != GL.GL_FRAMEBUFFER_COMPLETE:
        raise RenderBackendError(f"main framebuffer {W}x{H} incomplete")
    return fbo


def shadow_target(GL, S: int) -> tuple[int, int]:
    """(texture, framebuffer) of a new S x S shadow map: a float32 depth texture, linear filtered, clamped,
    compared (LEQUAL) when sampled; its framebuffer draws and reads no colour and is left bound."""
    tex = GL.glGenTextures(1)
    GL.glBindTexture(GL.GL_TEXTURE_2D, tex)
    GL.glTexImage2D(GL.GL_TEXTURE_2D, 0, GL.GL_DEPTH_COMPONENT32F, S, S, 0, GL.GL_DEPTH_COMPONENT, GL.GL_FLOAT, None)
    for p, v in [(GL.GL_TEXTURE_MIN_FILTER, GL.GL_LINEAR), (GL.GL_TEXTURE_MAG_FILTER, GL.GL_LINEAR),
                 (GL.GL_TEXTURE_WRAP_S, GL.GL_CLAMP_TO_EDGE), (GL.GL_TEXTURE_WRAP_T, GL.GL_CLAMP_TO_EDGE),
                 (GL.GL_TEXTURE_COMPARE_MODE, GL.GL_COMPARE_REF_TO_TEXTURE),
                 (GL.GL_TEXTURE_COMPARE_FUNC, GL.GL_LEQUAL)]:
        GL.glTexParameteri(GL.GL_TEXTURE_2D, p, v)
    fbo = GL.glGenFramebuffers(1)
    GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, fbo)
    GL.glFramebufferTexture2D(GL.GL_FRAMEBUFFER, GL.GL_DEPTH_ATTACHMENT, GL.GL_TEXTURE_2D, tex, 0)
    GL.glDrawBuffer(GL.GL_NONE)
    GL.glReadBuffer(GL.GL_NONE)
    if GL.glCheckFramebufferStatus(GL.GL_FRAMEBUFFER) != GL.GL_FRAMEBUFFER_COMPLETE:
        raise RenderBackendError("shadow framebuffer incomplete")
    return tex, fbo


def srgb_texture_array(GL, tex: int | None, images: np.ndarray, tiled: bool, unit: int | None = None) -> int:
    """Upload `images` ((L, S, S, 3) uint8 sRGB, C-contiguous, rows as stored) into texture array `tex` (a new
    one when None) and return it, left bound to texture unit `unit` (None: the active one). ``tiled``:
    mipmapped and repeating (the material textures); otherwise linear and clamped (the live ego's cube)."""
    if tex is None:
        tex = GL.glGenTextures(1)
    if unit is not None:
        GL.glActiveTexture(unit)
    L, S = images.shape[0], images.shape[1]
    GL.glBindTexture(GL.GL_TEXTURE_2D_ARRAY, tex)
    GL.glPixelStorei(GL.GL_UNPACK_ALIGNMENT, 1)
    GL.glTexImage3D(GL.GL_TEXTURE_2D_ARRAY, 0, GL.GL_SRGB8, S, S, L, 0, GL.GL_RGB, GL.GL_UNSIGNED_BYTE, images)
    if tiled:
        GL.glGenerateMipmap(GL.GL_TEXTURE_2D_ARRAY)
    lo, wrap = (GL.GL_LINEAR_MIPMAP_LINEAR, GL.GL_REPEAT) if tiled else (GL.GL_LINEAR, GL.GL_CLAMP_TO_EDGE)
    for p, v in [(GL.GL_TEXTURE_MIN_FILTER, lo), (GL.GL_TEXTURE_MAG_FILTER, GL.GL_LINEAR),
                 (GL.GL_TEXTURE_WRAP_S, wrap), (GL.GL_TEXTURE_WRAP_T, wrap)]:
        GL.glTexParameteri(GL.GL_TEXTURE_2D_ARRAY, p, v)
    return tex
