#version 330 core
// Terrain surface and skirts textured by a texture patch: uv from world x, y through the
// patch's extent; the texel is drawn as it is (decal) or modulated by the light. A grey
// shading texture (baked hillshade) shades the hypsometric palette instead.

#if defined VERTEX_SHADER

uniform mat4 u_mvp;          // local (world − origin) → clip
in vec3 in_position;         // world − origin, float32
in float in_skirt;           // 0 on the surface, 1 on skirt walls
out vec3 v_local;
out float v_skirt;

void main() {
    v_local = in_position;
    v_skirt = in_skirt;
    gl_Position = u_mvp * vec4(in_position, 1.0);
}

#elif defined FRAGMENT_SHADER

#include "include/terrain_shading.glsl"

uniform sampler2D u_texture; // RGBA8 texture patch with mipmaps, row 0 at v = 0
uniform vec4 u_tex_uv;       // uv = local.xy * u_tex_uv.xy + u_tex_uv.zw
uniform sampler2D u_normals; // RG8: normal x, y in display units, encoded as n * 0.5 + 0.5
uniform vec4 u_normal_uv;    // uv = local.xy * u_normal_uv.xy + u_normal_uv.zw
uniform float u_shade_texture; // 1: the texture is grey shading (hillshade), 0: colours
uniform float u_line;        // 1 when drawing wireframe lines
uniform float u_lighting;    // 1: GL_MODULATE with the light, 0: decal
in vec3 v_local;
in float v_skirt;
out vec4 f_color;

void main() {
    vec4 texel = texture(u_texture, v_local.xy * u_tex_uv.xy + u_tex_uv.zw);
#if defined DECAL
    // Colours drawn as they are (no light, no shading texture; the renderer's
    // "textured_decal"): no normal map fetched, no shading arithmetic (a sixth of a frame's
    // fill on llvmpipe, which runs every branch of a uniform choice).
    vec3 tint = hypsometric(v_local.z);
    vec3 colour = mix(tint, texel.rgb, texel.a);
#else
    vec3 tint = hypsometric(v_local.z);
    // Transparent texels (no texture data) show the hypsometric palette instead. A shading
    // texture is the light baked once: the palette times the shade, flat ground (the shade
    // of a 45° sun, 0.707) keeping the palette's colour.
    vec3 shaded = tint * clamp(0.3 + 0.7 * texel.r / 0.7071, 0.0, 1.25);
    vec3 base = mix(tint, mix(texel.rgb, shaded, u_shade_texture), texel.a);
    vec2 nxy = texture(u_normals, v_local.xy * u_normal_uv.xy + u_normal_uv.zw).rg * 2.0 - 1.0;
    vec3 normal = vec3(nxy, sqrt(max(1.0 - dot(nxy, nxy), 0.0)));
    vec3 colour = mix(base, lit(base, normal), u_lighting);
#endif
    vec4 wall = side_wall(v_local, v_skirt);
    colour = mix(colour, wall.rgb, wall.a);
    f_color = vec4(mix(colour, colour * 0.35, u_line), 1.0);
}

#endif
