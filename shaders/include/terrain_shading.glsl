// Shading helpers shared by the terrain programs: hypsometric colour ramp and lighting.

// Hypsometric tint: lowland green, hills yellow-brown, mountains brown, peaks near white.
// t: height normalised to [0, 1] over the terrain's z range.
vec3 hypsometric(float t) {
    const vec3 c0 = vec3(0.20, 0.45, 0.25);
    const vec3 c1 = vec3(0.55, 0.65, 0.35);
    const vec3 c2 = vec3(0.80, 0.72, 0.45);
    const vec3 c3 = vec3(0.60, 0.45, 0.32);
    const vec3 c4 = vec3(0.95, 0.95, 0.95);
    t = clamp(t, 0.0, 1.0);
    if (t < 0.25) return mix(c0, c1, t / 0.25);
    if (t < 0.50) return mix(c1, c2, (t - 0.25) / 0.25);
    if (t < 0.80) return mix(c2, c3, (t - 0.50) / 0.30);
    return mix(c3, c4, (t - 0.80) / 0.20);
}

// Lambert lighting with an ambient floor, light from the north-west at 45 degrees.
vec3 lit(vec3 base, vec3 normal) {
    const vec3 light = normalize(vec3(-1.0, 1.0, 1.4142));
    float diffuse = max(dot(normalize(normal), light), 0.0);
    return base * (0.35 + 0.65 * diffuse);
}
