#version 330 core
// Offscreen hillshade bake (core paper, 5.3): an orthographic top-down pass over one tile of
// the texture lattice, one fragment per texel. Each fragment reads the 3 × 3 height window
// around its texel from a height texture carrying a one-texel halo, so tiles join without
// seams, and evaluates gdaldem's formulas (see approxtree/kernels/hillshade.py, same names).

#if defined VERTEX_SHADER

in vec3 in_position;         // the tile's quad in clip space (orthographic, top-down)

void main() {
    gl_Position = vec4(in_position.xy, 0.0, 1.0);
}

#elif defined FRAGMENT_SHADER

uniform sampler2D u_heights; // RG32F: height − offset, valid flag; texel (i + 1, j + 1) = texel
                             // (i, j) of the tile, row j = lattice row (north first)
uniform int u_algorithm;     // 0 Horn, 1 Zevenbergen–Thorne
uniform int u_mode;          // 0 standard, 1 combined, 2 multidirectional
uniform vec2 u_inv_step;     // 1 / dx, 1 / dy (dy signed)
uniform float u_sin_alt;
uniform float u_cos_az;      // cos(azimuth) · cos(altitude) · z factor / (8 or 2)
uniform float u_sin_az;      // sin(azimuth) · cos(altitude) · z factor / (8 or 2)
uniform float u_c225;        // cos(225°) · cos(altitude) · z factor / (8 or 2)
uniform float u_cos_alt_z;   // cos(altitude) · z factor / (8 or 2)
uniform float u_square_z;    // (z factor / (8 or 2))²
out float f_shade;           // 1..255, 0 = nodata (gdaldem before rounding)

const float PI = 3.14159265358979;

void main() {
    ivec2 p = ivec2(gl_FragCoord.xy) + ivec2(1);
    // Window w[3 j + i] = row r − 1 + j, column c − 1 + i; any nodata leaves the texel nodata.
    vec2 t0 = texelFetchOffset(u_heights, p, 0, ivec2(-1, -1)).rg;
    vec2 t1 = texelFetchOffset(u_heights, p, 0, ivec2(0, -1)).rg;
    vec2 t2 = texelFetchOffset(u_heights, p, 0, ivec2(1, -1)).rg;
    vec2 t3 = texelFetchOffset(u_heights, p, 0, ivec2(-1, 0)).rg;
    vec2 t4 = texelFetch(u_heights, p, 0).rg;
    vec2 t5 = texelFetchOffset(u_heights, p, 0, ivec2(1, 0)).rg;
    vec2 t6 = texelFetchOffset(u_heights, p, 0, ivec2(-1, 1)).rg;
    vec2 t7 = texelFetchOffset(u_heights, p, 0, ivec2(0, 1)).rg;
    vec2 t8 = texelFetchOffset(u_heights, p, 0, ivec2(1, 1)).rg;
    float valid = min(min(min(t0.g, t1.g), min(t2.g, t3.g)),
                      min(min(t4.g, t5.g), min(min(t6.g, t7.g), t8.g)));
    if (valid < 0.5) {
        f_shade = 0.0;
        return;
    }
    float w[9] = float[9](t0.r, t1.r, t2.r, t3.r, t4.r, t5.r, t6.r, t7.r, t8.r);
    float x;
    float y;
    if (u_algorithm == 0) {
        x = ((w[0] + 2.0 * w[3] + w[6]) - (w[2] + 2.0 * w[5] + w[8])) * u_inv_step.x;
        y = ((w[6] + 2.0 * w[7] + w[8]) - (w[0] + 2.0 * w[1] + w[2])) * u_inv_step.y;
    } else {
        x = (w[3] - w[5]) * u_inv_step.x;
        y = (w[7] - w[1]) * u_inv_step.y;
    }
    float xx_yy = x * x + y * y;
    if (u_mode == 0) {
        float v = 254.0 * (u_sin_alt - (y * u_cos_az - x * u_sin_az))
                  / sqrt(1.0 + u_square_z * xx_yy);
        f_shade = v <= 0.0 ? 1.0 : 1.0 + v;
    } else if (u_mode == 1) {
        float slope = xx_yy * u_square_z;
        float cang = (u_sin_alt - (y * u_cos_az - x * u_sin_az)) / sqrt(1.0 + slope);
        cang = acos(clamp(cang, -1.0, 1.0));
        // Steeper cells get darker: weight the angle by the slope.
        cang = 1.0 - cang * atan(sqrt(slope)) / (PI * PI / 4.0);
        f_shade = cang <= 0.0 ? 1.0 : 1.0 + 254.0 * cang;
    } else {
        if (xx_yy == 0.0) {
            f_shade = 1.0 + 254.0 * u_sin_alt;
            return;
        }
        // Four lights (225°, 270°, 315°, 360°) weighted by the aspect (USGS OF 92-422).
        float v225 = max(0.0, 127.0 * (u_sin_alt + (x - y) * u_c225));
        float v270 = max(0.0, 127.0 * (u_sin_alt - x * u_cos_alt_z));
        float v315 = max(0.0, 127.0 * (u_sin_alt + (x + y) * u_c225));
        float v360 = max(0.0, 127.0 * (u_sin_alt - y * u_cos_alt_z));
        float w225 = 0.5 * xx_yy - x * y;
        float w270 = x * x;
        float w315 = xx_yy - w225;
        float w360 = y * y;
        float v = (w225 * v225 + w270 * v270 + w315 * v315 + w360 * v360) / xx_yy;
        f_shade = 1.0 + v / sqrt(1.0 + u_square_z * xx_yy);
    }
}

#endif
