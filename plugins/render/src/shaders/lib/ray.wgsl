// Ray helpers shared by every ray-cast glyph (SH glyphs, ellipsoids, tubelets, volume).
// Keep in sync with the f64 CPU references in `plugins/render/src/reference.rs`.
//
// Rule for every Fascicle shader: no `if` and no loop bound may depend on uniform values alone. Mesa 22.3's
// lavapipe (Debian 12's software Vulkan) specialises a shader on such values ("uniform inlining"); for
// our shaders it recompiled them at every pipeline bind and never freed the old ones, leaking 2-3 MB a
// frame (found by `fascicle soak`). Use `select`, or pass the setting flat from the vertex stage.
#define_import_path fascicle::ray

struct Ray {
    origin: vec3<f32>,
    dir: vec3<f32>,
};

// The view ray through a fragment at `world_pos` on a proxy surface. Perspective: from the camera
// centre; orthographic (clip_from_view[3].w == 1): along the view direction through the fragment.
// `select`, not `if`: the projection is a uniform (see the rule above).
fn view_ray(world_pos: vec3<f32>, camera_pos: vec3<f32>, world_from_view: mat4x4<f32>, clip_from_view: mat4x4<f32>) -> Ray {
    let ortho = clip_from_view[3].w == 1.0;
    let d = normalize(-world_from_view[2].xyz);
    return Ray(select(camera_pos, world_pos - d * 1.0e4, ortho), select(normalize(world_pos - camera_pos), d, ortho));
}

// Nearest positive hit of a ray with a sphere, or -1. Uses the numerically stable form of the quadratic.
fn ray_sphere(r: Ray, center: vec3<f32>, radius: f32) -> f32 {
    let oc = r.origin - center;
    let b = dot(oc, r.dir);
    let c = dot(oc, oc) - radius * radius;
    let h = b * b - c;
    if h < 0.0 {
        return -1.0;
    }
    let s = sqrt(h);
    let t0 = -b - s;
    if t0 > 0.0 {
        return t0;
    }
    let t1 = -b + s;
    return select(-1.0, t1, t1 > 0.0);
}

// Entry (clamped to 0) and exit distances of a unit ray through a sphere, the ray's origin given relative to
// the centre (`oc`); a miss or a sphere behind the ray gives y <= 0. The twin of
// `fascicle_core::sh::glyph::ray_sphere_interval`.
fn sphere_interval(oc: vec3<f32>, dir: vec3<f32>, radius: f32) -> vec2<f32> {
    let b = dot(oc, dir);
    let disc = b * b - (dot(oc, oc) - radius * radius);
    if disc < 0.0 {
        return vec2<f32>(0.0, -1.0);
    }
    let s = sqrt(disc);
    return vec2<f32>(max(-b - s, 0.0), -b + s);
}

// Entry and exit distances of a ray through an axis-aligned box (slab method); x > y means a miss.
fn ray_box(r: Ray, lo: vec3<f32>, hi: vec3<f32>) -> vec2<f32> {
    let inv = 1.0 / r.dir;
    let a = (lo - r.origin) * inv;
    let b = (hi - r.origin) * inv;
    let tmin = min(a, b);
    let tmax = max(a, b);
    return vec2<f32>(max(max(tmin.x, tmin.y), max(tmin.z, 0.0)), min(min(tmax.x, tmax.y), tmax.z));
}

// Depth to write to @builtin(frag_depth) (not named frag_depth: imports are substituted textually): clip z / clip w of a world point (reverse-Z in Bevy: near = 1).
fn depth_of(clip_from_world: mat4x4<f32>, p: vec3<f32>) -> f32 {
    let c = clip_from_world * vec4<f32>(p, 1.0);
    return c.z / c.w;
}
