// Hyperstreamlines (SEEDS.md section 3): each tubelet (a streamline segment with elliptical end sections
// from the tensors) ray cast per pixel on its bounding box: from where the ray enters the bounding
// cylinder, step to the elliptic cylinder whose section is frozen at the current point (a quadratic; else a
// secant or linear step), then regula falsi once the surface is bracketed (`iterations` evaluations at
// most; or, as the baseline, the seed's sphere tracing), discard outside the cut planes,
// normal from the implicit function's gradient, headlight Phong, true fragment depth. The f64 twins are
// `fascicle_core::tubelet::Tubelet::{trace_bracketed, trace_sphere}`; keep `TubeParams` in sync with `TubeUniform` in
// `plugins/tracts/src/lib.rs`. One draw per set: the mesh holds 8 vertices per tubelet, (slot, corner, 0).

#import bevy_pbr::mesh_view_bindings::view
#import fascicle::ray::{Ray, view_ray, depth_of}

struct TubeParams {
    iterations: u32,
    eps: f32,
    ambient: f32,
    specular: f32,
    shininess: f32,
    // 0: frozen-section steps and regula falsi; 1: the seed's sphere tracing.
    method: u32,
};

@group(#{MATERIAL_BIND_GROUP}) @binding(0) var<uniform> params: TubeParams;
// Seven vec4 per tubelet: (centre, h), quaternion, (ry_l, rz_l, ry_r, rz_r), (cut_l, twist),
// (cut_r, streamline bits), (colour_l, 0), (colour_r, 0).
@group(#{MATERIAL_BIND_GROUP}) @binding(1) var<storage, read> tubes: array<vec4<f32>>;
// One bit per streamline, set when selected: bit s % 32 of word s / 32 (`selection_words`).
@group(#{MATERIAL_BIND_GROUP}) @binding(2) var<storage, read> selected: array<u32>;

const TWIST_STEP: f32 = 0.15;

struct Tube {
    centre: vec3<f32>,
    h: f32,
    q: vec4<f32>,
    radii: vec4<f32>,
    cut_l: vec3<f32>,
    twist: f32,
    cut_r: vec3<f32>,
    streamline: u32,
};

fn load(slot: u32) -> Tube {
    let b = 7u * slot;
    let a0 = tubes[b];
    let a3 = tubes[b + 3u];
    let a4 = tubes[b + 4u];
    return Tube(a0.xyz, a0.w, tubes[b + 1u], tubes[b + 2u], a3.xyz, a3.w, a4.xyz, bitcast<u32>(a4.w));
}

fn rotate(q: vec4<f32>, v: vec3<f32>) -> vec3<f32> {
    return v + 2.0 * cross(q.xyz, cross(q.xyz, v) + q.w * v);
}

fn unrotate(q: vec4<f32>, v: vec3<f32>) -> vec3<f32> {
    return rotate(vec4<f32>(-q.xyz, q.w), v);
}

fn rmax(t: Tube) -> f32 {
    return max(max(t.radii.x, t.radii.y), max(t.radii.z, t.radii.w));
}

fn half_extents(t: Tube) -> vec3<f32> {
    let r = rmax(t) * 1.01;
    let el = r * sqrt(max(1.0 - t.cut_l.x * t.cut_l.x, 0.0)) / max(t.cut_l.x, 1e-3);
    let er = r * sqrt(max(1.0 - t.cut_r.x * t.cut_r.x, 0.0)) / max(t.cut_r.x, 1e-3);
    return vec3<f32>(t.h + max(el, er), r, r);
}

// (r1, r2, rho, s) at local x.
fn section(t: Tube, x: f32) -> vec4<f32> {
    let s = select(0.5, clamp((x + t.h) / (2.0 * t.h), 0.0, 1.0), t.h > 0.0);
    return vec4<f32>(mix(t.radii.x, t.radii.z, s), mix(t.radii.y, t.radii.w, s), s * t.twist, s);
}

fn f(t: Tube, p: vec3<f32>) -> f32 {
    let sec = section(t, p.x);
    let phi = atan2(p.z, p.y) - sec.z;
    let c = cos(phi);
    let s = sin(phi);
    let r = sec.x * sec.y / max(sqrt((sec.y * c) * (sec.y * c) + (sec.x * s) * (sec.x * s)), 1e-30);
    return length(p.yz) - r;
}

fn between_cuts(t: Tube, p: vec3<f32>) -> bool {
    return dot(p - vec3<f32>(-t.h, 0.0, 0.0), t.cut_l) >= 0.0 && dot(p - vec3<f32>(t.h, 0.0, 0.0), t.cut_r) <= 0.0;
}

struct TubeVertex {
    // (slot, corner index 0..7, 0)
    @location(0) position: vec3<f32>,
};

struct TubeVertexOutput {
    @builtin(position) clip_position: vec4<f32>,
    @location(0) world_position: vec3<f32>,
    @location(1) @interpolate(flat) slot: u32,
    // `params.iterations`, flat: the fragment stage must not bound its loop by a uniform (the rule in
    // `fascicle::ray`).
    @location(2) @interpolate(flat) iterations: u32,
    // `params.method`, flat for the same reason.
    @location(3) @interpolate(flat) method: u32,
};

@vertex
fn vertex(v: TubeVertex) -> TubeVertexOutput {
    var out: TubeVertexOutput;
    let slot = u32(v.position.x);
    let corner = u32(v.position.y);
    let t = load(slot);
    let sign = vec3<f32>(
        select(-1.0, 1.0, (corner & 1u) != 0u),
        select(-1.0, 1.0, (corner & 2u) != 0u),
        select(-1.0, 1.0, (corner & 4u) != 0u),
    );
    let hidden = ((selected[t.streamline >> 5u] >> (t.streamline & 31u)) & 1u) == 0u;
    let w = t.centre + rotate(t.q, sign * half_extents(t));
    out.world_position = w;
    out.clip_position = select(view.clip_from_world * vec4<f32>(w, 1.0), vec4<f32>(2.0, 2.0, 2.0, 1.0), hidden);
    out.slot = slot;
    out.iterations = params.iterations;
    out.method = params.method;
    return out;
}

// Where the local ray first enters, within [t0, t1], the frustum about x whose radius goes linearly from r_l
// at x = -h to r_r at x = h (t0 when it starts inside); -1 when it does not.
fn frustum_entry(t: Tube, o: vec3<f32>, d: vec3<f32>, t0: f32, t1: f32, r_l: f32, r_r: f32) -> f32 {
    let slope = select(0.0, (r_r - r_l) / (2.0 * t.h), t.h > 0.0);
    let ra = 0.5 * (r_l + r_r) + slope * o.x;
    let rb = slope * d.x;
    let p0 = o + d * t0;
    if length(p0.yz) <= ra + rb * t0 {
        return t0;
    }
    let qa = d.y * d.y + d.z * d.z - rb * rb;
    let qb = o.y * d.y + o.z * d.z - ra * rb;
    let qc = o.y * o.y + o.z * o.z - ra * ra;
    var r0 = -1.0;
    var r1 = -1.0;
    if abs(qa) < 1e-12 {
        if abs(qb) > 1e-30 {
            r0 = -qc / (2.0 * qb);
            r1 = r0;
        }
    } else {
        let disc = qb * qb - qa * qc;
        if disc < 0.0 {
            return -1.0;
        }
        let q = sqrt(disc);
        let a = (-qb - q) / qa;
        let b = (-qb + q) / qa;
        r0 = min(a, b);
        r1 = max(a, b);
    }
    if r0 >= t0 && r0 <= t1 && ra + rb * r0 >= 0.0 {
        return r0;
    }
    if r1 >= t0 && r1 <= t1 && ra + rb * r1 >= 0.0 {
        return r1;
    }
    return -1.0;
}

// The seed's sphere tracing (twin: `Tubelet::trace_sphere`): from midway between the entries into the
// frustums through the major and the minor semi-axes, steps of the signed in-plane gap f. (t, 1) on a hit.
fn trace_sphere(t: Tube, o: vec3<f32>, d: vec3<f32>, t0: f32, t1: f32, iterations: u32, tol: f32) -> vec2<f32> {
    let outer = frustum_entry(t, o, d, t0, t1, max(t.radii.x, t.radii.y), max(t.radii.z, t.radii.w));
    if outer < 0.0 {
        return vec2<f32>(0.0, 0.0);
    }
    let inner = frustum_entry(t, o, d, t0, t1, min(t.radii.x, t.radii.y), min(t.radii.z, t.radii.w));
    var tt = select(outer, 0.5 * (outer + inner), inner >= 0.0);
    for (var k = 0u; k < iterations; k++) {
        let v = f(t, o + d * tt);
        if abs(v) < tol {
            return vec2<f32>(tt, select(0.0, 1.0, tt >= t0 && tt <= t1));
        }
        tt += v;
    }
    return vec2<f32>(tt, 0.0);
}

struct FragmentOutput {
    @location(0) color: vec4<f32>,
    @builtin(frag_depth) depth: f32,
};

// Frozen-section steps, then regula falsi in the bracket (twin: `Tubelet::trace_bracketed`). (t, 1) on a hit.
fn trace_bracketed(t: Tube, o: vec3<f32>, d: vec3<f32>, t0: f32, t1: f32, iterations: u32, tol: f32) -> vec2<f32> {
    // A twisted section turns by at most TWIST_STEP radians per step (thin sections are not stepped over).
    var max_step = 1e30;
    if abs(t.twist) > 1e-6 {
        max_step = 2.0 * t.h * (TWIST_STEP / abs(t.twist)) / max(abs(d.x), 1e-3);
    }
    var tt = t0;
    var hit = false;
    // Last sample outside (t, f), first inside after it (y < 0 once bracketed), previous outside sample.
    var out_s = vec2<f32>(t0, -1.0);
    var in_s = vec2<f32>(0.0, 1.0);
    var prev = vec2<f32>(0.0, -1.0);
    for (var k = 0u; k < iterations; k++) {
        let p = o + d * tt;
        let v = f(t, p);
        if abs(v) < tol {
            hit = true;
            break;
        }
        if v < 0.0 {
            in_s = vec2<f32>(tt, v);
        } else {
            prev = out_s;
            out_s = vec2<f32>(tt, v);
            if in_s.y > 0.0 {
                let sec = section(t, p.x);
                let c = cos(sec.z);
                let s = sin(sec.z);
                let py = p.y * c + p.z * s;
                let pz = -p.y * s + p.z * c;
                let dy = d.y * c + d.z * s;
                let dz = -d.y * s + d.z * c;
                let a2 = sec.x * sec.x;
                let b2 = sec.y * sec.y;
                let ka = dy * dy / a2 + dz * dz / b2;
                let kb = py * dy / a2 + pz * dz / b2;
                let kc = py * py / a2 + pz * pz / b2 - 1.0;
                let disc = kb * kb - ka * kc;
                var frozen = -1.0;
                if ka > 1e-30 && disc >= 0.0 {
                    frozen = (-kb - sqrt(disc)) / ka;
                }
                var secant = -1.0;
                if prev.y > v {
                    secant = v * (tt - prev.x) / (prev.y - v);
                }
                var step = (t1 - t0) / f32(iterations);
                if frozen >= 0.0 && tt + frozen <= t1 {
                    step = frozen;
                } else if secant > 0.0 && tt + secant <= t1 {
                    step = secant;
                }
                tt += min(step, max_step);
                if tt > t1 {
                    break;
                }
                continue;
            }
        }
        // Bracketed: regula falsi.
        tt = out_s.x + (in_s.x - out_s.x) * out_s.y / (out_s.y - in_s.y);
        if abs(in_s.x - out_s.x) < tol {
            break;
        }
    }
    if !hit {
        hit = abs(f(t, o + d * tt)) < tol && tt <= t1;
    }
    return vec2<f32>(tt, select(0.0, 1.0, hit));
}

@fragment
fn fragment(in: TubeVertexOutput) -> FragmentOutput {
    let t = load(in.slot);
    let ray = view_ray(in.world_position, view.world_position, view.world_from_view, view.clip_from_view);
    let o = unrotate(t.q, ray.origin - t.centre);
    let d = unrotate(t.q, ray.dir);
    // Bounding box, then bounding cylinder.
    let hi = half_extents(t);
    let inv = 1.0 / d;
    let a = (-hi - o) * inv;
    let b = (hi - o) * inv;
    var t0 = max(max(min(a.x, b.x), min(a.y, b.y)), max(min(a.z, b.z), 0.0));
    var t1 = min(min(max(a.x, b.x), max(a.y, b.y)), max(a.z, b.z));
    // The box interval: the sphere tracer's range (its twin has no bounding cylinder).
    let box0 = t0;
    let box1 = t1;
    let r = hi.y;
    let qa = d.y * d.y + d.z * d.z;
    let qb = o.y * d.y + o.z * d.z;
    let qc = o.y * o.y + o.z * o.z - r * r;
    if qa >= 1e-12 {
        let disc = qb * qb - qa * qc;
        if disc < 0.0 {
            discard;
        }
        let sq = sqrt(disc);
        t0 = max(t0, (-qb - sq) / qa);
        t1 = min(t1, (-qb + sq) / qa);
    } else if qc > 0.0 {
        discard;
    }
    if t0 >= t1 {
        discard;
    }
    let tol = params.eps * rmax(t);
    var tt = t0;
    var hit = false;
    if in.method == 1u {
        let found = trace_sphere(t, o, d, box0, box1, in.iterations, tol);
        tt = found.x;
        hit = found.y > 0.0;
    } else {
        let found = trace_bracketed(t, o, d, t0, t1, in.iterations, tol);
        tt = found.x;
        hit = found.y > 0.0;
    }
    let p = o + d * tt;
    if !hit || !between_cuts(t, p) {
        discard;
    }
    // Normal: gradient of f by central differences, in world space.
    let e = 1e-3 * rmax(t);
    let g = vec3<f32>(
        f(t, p + vec3<f32>(e, 0.0, 0.0)) - f(t, p - vec3<f32>(e, 0.0, 0.0)),
        f(t, p + vec3<f32>(0.0, e, 0.0)) - f(t, p - vec3<f32>(0.0, e, 0.0)),
        f(t, p + vec3<f32>(0.0, 0.0, e)) - f(t, p - vec3<f32>(0.0, 0.0, e)),
    );
    let n = normalize(rotate(t.q, g));
    let s = section(t, p.x).w;
    let base = mix(tubes[7u * in.slot + 5u].xyz, tubes[7u * in.slot + 6u].xyz, s);
    let ndv = abs(dot(n, ray.dir));
    var out: FragmentOutput;
    out.color = vec4<f32>(base * (params.ambient + (1.0 - params.ambient) * ndv) + vec3<f32>(params.specular * pow(ndv, params.shininess)), 1.0);
    out.depth = depth_of(view.clip_from_world, t.centre + rotate(t.q, p));
    return out;
}
