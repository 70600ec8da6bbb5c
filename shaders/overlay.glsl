#version 330 core
// Viewer overlay: a text image (RGBA, straight alpha) on a screen-aligned quad.
// The quad's corners (0 or 1 in x and y) come in in_position, the registry's attribute.

#if defined VERTEX_SHADER

uniform vec4 u_rect;         // quad in normalised device coordinates: x0, y0, x1, y1
in vec3 in_position;         // corner of the unit square (z unused)
out vec2 v_uv;

void main() {
    vec2 corner = in_position.xy;
    v_uv = vec2(corner.x, 1.0 - corner.y);
    gl_Position = vec4(mix(u_rect.xy, u_rect.zw, corner), 0.0, 1.0);
}

#elif defined FRAGMENT_SHADER

uniform sampler2D u_text;    // RGBA8, row 0 at the top of the text
in vec2 v_uv;
out vec4 f_color;

void main() {
    f_color = texture(u_text, v_uv);
}

#endif
