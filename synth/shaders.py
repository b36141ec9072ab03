"""GLSL 330 sources of the renderer (`synth.gl_backend`): the main pass (RGB, camera-frame z, ego
flag, object id and material layer), the shadow-map pass and the sky.
"""
from __future__ import annotations


_GLSL_TO_SRGB = """
vec3 to_srgb(vec3 c) {
    c = clamp(c, 0.0, 1.0);
    return mix(c * 12.92, 1.055 * pow(c, vec3(1.0 / 2.4)) - 0.055, step(vec3(0.0031308), c));
}
"""

VS_MAIN = """
#version 330 core
layout(location=0) in vec3 a_pos;
layout(location=1) in vec3 a_nrm;
layout(location=2) in vec2 a_uv;
layout(location=3) in float a_layer;
layout(location=4) in vec3 a_tint;
layout(location=5) in float a_instance;
uniform float u_instance;  // >= 0: the object id of the whole draw (a mover), else the vertices' own
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
flat out float v_instance;
out vec3 v_pos_w;
out vec3 v_pos_o;
void main() {
    v_instance = u_instance >= 0.0 ? u_instance : a_instance;
    vec4 pc = u_modelview * vec4(a_pos, 1.0);
    vec4 pw = u_model * vec4(a_pos, 1.0);
    v_zcam = pc.z;
    v_dist = length(pc.xyz);
    v_nrm_w = mat3(u_model) * a_nrm;
    v_uv = a_uv;
    v_layer = a_layer;
    v_tint = a_tint;
    v_light = u_light_vp * pw;
    v_pos_w = pw.xyz;
    v_pos_o = a_pos;
    gl_Position = u_proj * pc;
}
"""

FS_MAIN = """
#version 330 core
in vec3 v_nrm_w;
in vec2 v_uv;
flat in float v_layer;
in vec3 v_tint;
in float v_zcam;
in float v_dist;
in vec4 v_light;
flat in float v_instance;
in vec3 v_pos_w;
in vec3 v_pos_o;
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
uniform float u_zfar;        // the depth test compares camera-frame z / zfar (see gl_backend)
// ego.appearance=live (synth.config.EgoConfig): the ego body's clear coat reflects the world around it
uniform int u_ego_live;
uniform sampler2DArray u_env;    // six sRGB cube faces of this frame's world without the ego, rows top first
uniform mat3 u_env_R[6];         // face camera (OpenCV) <- world; face i looks along world +x, -x, +y, -y, +z, -z
uniform vec3 u_cam_pos;          // world
uniform float u_ego_matte_layer; // the tyres: no clear coat
uniform mat4 u_model;            // world <- object (the vertex stage's)
uniform vec3 u_ego_centre;       // the body's box (object frame): a real body's panels are curved, its
uniform vec3 u_ego_half;         // reflection normal leans towards the box's ellipsoid's
layout(location=0) out vec4 o_color;
layout(location=1) out vec4 o_depth;
%(to_srgb)s
vec3 env_radiance(vec3 r) {  // linear RGB of the cube along world direction r
    vec3 a = abs(r);
    int i = (a.x >= a.y && a.x >= a.z) ? (r.x > 0.0 ? 0 : 1) : (a.y >= a.z ? (r.y > 0.0 ? 2 : 3) : (r.z > 0.0 ? 4 : 5));
    vec3 q = u_env_R[i] * r;  // q.z: the major component, > 0; 90 deg faces: K = (S/2, S/2, S/2, S/2)
    return texture(u_env, vec3(0.5 + 0.5 * q.x / q.z, 0.5 + 0.5 * q.y / q.z, float(i))).rgb;
}
void main() {
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
    if (u_ego_live == 1 && u_is_ego > 0.5 && abs(v_layer - u_ego_matte_layer) > 0.5) {
        // a clear coat: Schlick's Fresnel (F0 = 0.04) mixes in the mirrored world and the sun's highlight,
        // which the shadow map darkens with the rest
        vec3 v = normalize(v_pos_w - u_cam_pos);
        vec3 nr = normalize(n + normalize(mat3(u_model) * ((v_pos_o - u_ego_centre) / (u_ego_half * u_ego_half))));
        if (dot(nr, v) > 0.0) nr = n;  // leaning away from the camera: the flat panel's
        vec3 r = reflect(v, nr);
        float F = 0.04 + 0.96 * pow(1.0 - clamp(-dot(v, nr), 0.0, 1.0), 5.0);
        float spec = pow(max(dot(r, u_sun_dir), 0.0), 300.0) * 4.0 * lit;
        c = mix(c, env_radiance(r), F) + F * spec * u_sun_rgb;
    }
    float f = 1.0 - exp(-v_dist / u_fog_dist);
    c = mix(c, u_fog_rgb, f);
    o_color = vec4(to_srgb(c * u_gain), 1.0);
    // behind the camera: never visible, but z / zfar < 0 clamps to depth 0 and would win the depth test
    // (llvmpipe rasterised one such fragment at -24.06 m: tests/synth/test_depth_sign.py)
    if (v_zcam <= 0.0) discard;
    o_depth = vec4(v_zcam, u_is_ego, v_instance, v_layer);
    gl_FragDepth = v_zcam / u_zfar;
}
"""

FS_MAIN = FS_MAIN % {"to_srgb": _GLSL_TO_SRGB}

VS_SHADOW = """
#version 330 core
layout(location=0) in vec3 a_pos;
uniform mat4 u_light_mvp;
void main() { gl_Position = u_light_mvp * vec4(a_pos, 1.0); }
"""

FS_SHADOW = """
#version 330 core
void main() { }
"""

VS_SKY = """
#version 330 core
const vec2 P[3] = vec2[3](vec2(-1.0, -1.0), vec2(3.0, -1.0), vec2(-1.0, 3.0));
void main() { gl_Position = vec4(P[gl_VertexID], 1.0, 1.0); }
"""

FS_SKY = """
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
layout(location=1) out vec4 o_depth;
%(to_srgb)svoid main() {
    vec2 uv = vec2(gl_FragCoord.x, u_height - gl_FragCoord.y);   // OpenCV pixel coordinates
    vec3 d = normalize(u_R_world_cam * (u_K_inv * vec3(uv, 1.0)));
    float t = clamp(d.z, 0.0, 1.0);
    vec3 c = mix(u_horizon_rgb, u_zenith_rgb, pow(t, 0.6));
    if (d.z < 0.0) c = u_horizon_rgb * 0.8;
    float s = max(dot(d, u_sun_dir), 0.0);
    c += u_sun_rgb * (0.25 * pow(s, 64.0) + 2.0 * pow(s, 2000.0));
    o_color = vec4(to_srgb(c * u_gain), 1.0);
    o_depth = vec4(0.0, 0.0, 0.0, -1.0);
}
"""


FS_SKY = FS_SKY % {"to_srgb": _GLSL_TO_SRGB}
