#version 330 core
// World-position buffer: local coordinates of the visible surface, w = 1 on the surface and
// 0 on skirts (so checks can leave skirt pixels out).

#if defined VERTEX_SHADER

uniform mat4 u_mvp;
in vec3 in_position;
in float in_skirt;
out vec3 v_local;
out float v_skirt;

void main() {
    v_local = in_position;
    v_skirt = in_skirt;
    gl_Position = u_mvp * vec4(in_position, 1.0);
}

#elif defined FRAGMENT_SHADER

in vec3 v_local;
in float v_skirt;
out vec4 f_position;

void main() {
    f_position = vec4(v_local, v_skirt > 0.0 ? 0.0 : 1.0);
}

#endif
