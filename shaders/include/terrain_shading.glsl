// Shading helpers shared by the terrain programs: hypsometric palette, sun, side walls.

uniform sampler2D u_palette; // (n × 1) RGB8 hypsometric palette (approxtree.textures.palettes)
uniform vec2 u_palette_z;    // local z at the centres of the palette's first and last texels
uniform vec3 u_light;        // unit vector towards the sun, display coordinates (x east, y north)
uniform vec3 u_wall;         // colour of the walls along the terrain's outer border
uniform vec4 u_domain;       // the terrain's domain in local coordinates: xmin, ymin, xmax, ymax
uniform float u_domain_tol;  // distance (local units) within which a wall lies on the border

// Palette colour at local height z (constant beyond the palette's ends).
vec3 hypsometric(float z) {
    float n = float(textureSize(u_palette, 0).x);
    float t = clamp((z - u_palette_z.x) / max(u_palette_z.y - u_palette_z.x, 1e-6), 0.0, 1.0);
    return texture(u_palette, vec2((t * (n - 1.0) + 0.5) / n, 0.5)).rgb;
}

// Lambert lighting with an ambient floor, light from the sun (u_light).
vec3 lit(vec3 base, vec3 normal) {
    float diffuse = max(dot(normalize(normal), u_light), 0.0);
    return base * (0.35 + 0.65 * diffuse);
}

// Skirt fragments (skirt > 0) on the domain's outer border are side walls: drawn in the wall
// colour, lit from their outward normal; interior skirts (hidden under the surface, seen only
// through T-junction gaps) keep the surface colour. Returns 0 alpha when not a side wall.
vec4 side_wall(vec3 local, float skirt) {
    if (skirt <= 0.0) return vec4(0.0);
    vec2 lo = abs(local.xy - u_domain.xy);
    vec2 hi = abs(local.xy - u_domain.zw);
    vec3 n;
    if (lo.x <= u_domain_tol) n = vec3(-1.0, 0.0, 0.0);
    else if (hi.x <= u_domain_tol) n = vec3(1.0, 0.0, 0.0);
    else if (lo.y <= u_domain_tol) n = vec3(0.0, -1.0, 0.0);
    else if (hi.y <= u_domain_tol) n = vec3(0.0, 1.0, 0.0);
    else return vec4(0.0);
    float diffuse = max(dot(n, u_light), 0.0);
    return vec4(u_wall * (0.6 + 0.4 * diffuse), 1.0);
}
