#version 330 core
// Terrain surface and skirts: per-pixel normals from the normal map, hypsometric palette by
// elevation, side walls in the wall colour.

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

uniform sampler2D u_normals; // RG8: normal x, y in display units, encoded as n * 0.5 + 0.5
uniform vec4 u_normal_uv;    // uv = local.xy * u_normal_uv.xy + u_normal_uv.zw
uniform float u_line;        // 1 when drawing wireframe lines
uniform float u_lighting;    // 1: lit by the light, 0: the colour as it is
in vec3 v_local;
in float v_skirt;
out vec4 f_color;

void main() {
    vec2 nxy = texture(u_normals, v_local.xy * u_normal_uv.xy + u_normal_uv.zw).rg * 2.0 - 1.0;
    vec3 normal = vec3(nxy, sqrt(max(1.0 - dot(nxy, nxy), 0.0)));
    vec3 base = hypsometric(v_local.z);
    vec3 colour = mix(base, lit(base, normal), u_lighting);
    vec4 wall = side_wall(v_local, v_skirt);
    colour = mix(colour, wall.rgb, wall.a);
    f_color = vec4(mix(colour, colour * 0.35, u_line), 1.0);
}

#endif
