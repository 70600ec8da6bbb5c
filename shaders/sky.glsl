#version 330 core
// Background behind the terrain: a vertical gradient over the whole viewport (one colour when
// both ends agree), drawn after the terrain at the far plane where nothing else was drawn.

#if defined VERTEX_SHADER

in vec3 in_position;         // corner of a full-screen triangle in NDC (z unused)
out float v_height;          // 0 at the bottom of the viewport, 1 at its top

void main() {
    v_height = in_position.y * 0.5 + 0.5;
    gl_Position = vec4(in_position.xy, 1.0, 1.0);
}

#elif defined FRAGMENT_SHADER

uniform vec3 u_top;          // colour at the top of the image
uniform vec3 u_bottom;       // colour at the bottom (towards the horizon)
in float v_height;
out vec4 f_color;

void main() {
    // Pale near the horizon, deepening upwards (eased, as an atmosphere does).
    float t = clamp(v_height, 0.0, 1.0);
    // Alpha 0: the background is no terrain (drawn only where depth is still 1).
    f_color = vec4(mix(u_bottom, u_top, t * (2.0 - t)), 0.0);
}

#endif
