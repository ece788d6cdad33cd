// Ray-cast tensor glyphs: ellipsoids (closed-form ray-quadric intersection) and Kindlmann's superquadrics
// (linear search + bisection on the implicit function), exact normals, true fragment depth, on a bounding
// cube proxy per glyph. The f64 twin is `fascicle_core::dti::glyph`; keep `TensorParams` in sync with
// `TensorGlyphUniform` in `plugins/tensors/src/lib.rs`.

#import fascicle::proxy::{ProxyVertex, ProxyVertexOutput, proxy_glyph, proxy_vertex}
#import bevy_pbr::mesh_view_bindings::view
#import fascicle::ray::{Ray, view_ray, depth_of, sphere_interval}
#import fascicle::lighting::headlight
#import fascicle::colormap::viridis

struct TensorParams {
    // 0: ellipsoid, 1: superquadric
    shape: u32,
    gamma: f32,
    h: f32,
    refine: u32,
    // 0: |e1| RGB weighted by FA, 1: FA through viridis, 2: normal as colour (tests)
    colour_mode: u32,
    ambient: f32,
    max_steps: u32,
    min_exponent: f32,
};

@group(#{MATERIAL_BIND_GROUP}) @binding(0) var<uniform> params: TensorParams;
// Five vec4 per glyph: (centre, bound), (e1, r1), (e2, r2), (e3, r3), (cl, cp, fa, 0).
@group(#{MATERIAL_BIND_GROUP}) @binding(1) var<storage, read> glyphs: array<vec4<f32>>;

@vertex
fn vertex(v: ProxyVertex) -> ProxyVertexOutput {
    // Loop counts and modes reach the fragment stage flat (the rule in `fascicle::ray`).
    // The glyph's cube: its centre plus or minus its bound.
    let a0 = glyphs[5u * proxy_glyph(v)];
    return proxy_vertex(v, a0.xyz, vec3<f32>(a0.w), vec4<u32>(params.shape, params.colour_mode, params.refine, params.max_steps));
}

struct FragmentOutput {
    @location(0) color: vec4<f32>,
    @builtin(frag_depth) depth: f32,
};

struct Glyph {
    centre: vec3<f32>,
    bound: f32,
    e1: vec3<f32>,
    e2: vec3<f32>,
    e3: vec3<f32>,
    radii: vec3<f32>,
    cl: f32,
    cp: f32,
    fa: f32,
};

fn load_glyph(tag: u32) -> Glyph {
    let b = 5u * tag;
    let a0 = glyphs[b];
    let a1 = glyphs[b + 1u];
    let a2 = glyphs[b + 2u];
    let a3 = glyphs[b + 3u];
    let a4 = glyphs[b + 4u];
    return Glyph(a0.xyz, a0.w, a1.xyz, a2.xyz, a3.xyz, vec3<f32>(a1.w, a2.w, a3.w), a4.x, a4.y, a4.z);
}

// Glyph-frame coordinates of a point given relative to the centre.
fn local(g: Glyph, v: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(dot(v, g.e1), dot(v, g.e2), dot(v, g.e3)) / g.radii;
}

// (alpha, beta, symmetry axis 0 = e1 / 2 = e3).
fn exponents(g: Glyph) -> vec3<f32> {
    let ecl = max(pow(max(1.0 - g.cl, 0.0), params.gamma), params.min_exponent);
    let ecp = max(pow(max(1.0 - g.cp, 0.0), params.gamma), params.min_exponent);
    if g.cl >= g.cp {
        return vec3<f32>(ecp, ecl, 0.0);
    }
    return vec3<f32>(ecl, ecp, 2.0);
}

fn superquadric(q: vec3<f32>, e: vec3<f32>) -> f32 {
    var uvw = q;
    if e.z == 0.0 {
        uvw = vec3<f32>(q.y, q.z, q.x);
    }
    let s = pow(abs(uvw.x), 2.0 / e.x) + pow(abs(uvw.y), 2.0 / e.x);
    return pow(s, e.x / e.y) + pow(abs(uvw.z), 2.0 / e.y) - 1.0;
}

fn superquadric_gradient(q: vec3<f32>, e: vec3<f32>) -> vec3<f32> {
    var uvw = q;
    if e.z == 0.0 {
        uvw = vec3<f32>(q.y, q.z, q.x);
    }
    let s = pow(abs(uvw.x), 2.0 / e.x) + pow(abs(uvw.y), 2.0 / e.x);
    let k = select(0.0, pow(s, e.x / e.y - 1.0), s > 0.0);
    let du = k * pow(abs(uvw.x), 2.0 / e.x - 1.0) * sign(uvw.x);
    let dv = k * pow(abs(uvw.y), 2.0 / e.x - 1.0) * sign(uvw.y);
    let dw = pow(abs(uvw.z), 2.0 / e.y - 1.0) * sign(uvw.z);
    if e.z == 0.0 {
        return vec3<f32>(dw, du, dv);
    }
    return vec3<f32>(du, dv, dw);
}

@fragment
fn fragment(in: ProxyVertexOutput) -> FragmentOutput {
    // Integer settings, flat from the vertex stage (the rule in `fascicle::ray`).
    let shape = in.knobs.x;
    let colour_mode = in.knobs.y;
    let refine = in.knobs.z;
    let max_steps = in.knobs.w;
    let g = load_glyph(in.tag);
    let ray = view_ray(in.world_position, view.world_position, view.world_from_view, view.clip_from_view);
    let oc = ray.origin - g.centre;
    var t_hit = -1.0;
    var grad_local = vec3<f32>(0.0);
    if shape == 0u {
        let oq = local(g, oc);
        let dq = local(g, ray.dir);
        let a = dot(dq, dq);
        let b = dot(oq, dq);
        let c = dot(oq, oq) - 1.0;
        let disc = b * b - a * c;
        if disc < 0.0 {
            discard;
        }
        let s = sqrt(disc);
        let qq = -(b + select(-s, s, b >= 0.0));
        var t0 = c / qq;
        var t1 = qq / a;
        if qq == 0.0 {
            t0 = -b / a;
            t1 = t0;
        }
        let tn = min(t0, t1);
        let tf = max(t0, t1);
        t_hit = select(tf, tn, tn > 0.0);
        if t_hit <= 0.0 {
            discard;
        }
        grad_local = oq + t_hit * dq;
    } else {
        let e = exponents(g);
        let span = sphere_interval(oc, ray.dir, g.bound);
        if span.y <= 0.0 {
            discard;
        }
        let t0 = span.x;
        let t1 = span.y;
        let step = max(params.h, 1e-4) * g.bound;
        var lo = t0;
        var t = t0;
        var inside = false;
        for (var i = 0u; i < max_steps; i++) {
            if superquadric(local(g, oc + t * ray.dir), e) < 0.0 {
                inside = true;
                break;
            }
            lo = t;
            if t >= t1 {
                break;
            }
            t = min(t + step, t1);
        }
        if !inside {
            discard;
        }
        var hi = t;
        for (var k = 0u; k < refine; k++) {
            let mid = 0.5 * (lo + hi);
            if superquadric(local(g, oc + mid * ray.dir), e) < 0.0 {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        t_hit = hi;
        grad_local = superquadric_gradient(local(g, oc + t_hit * ray.dir), e);
    }
    let v = oc + t_hit * ray.dir;
    var n = g.e1 * (grad_local.x / g.radii.x) + g.e2 * (grad_local.y / g.radii.y) + g.e3 * (grad_local.z / g.radii.z);
    n = select(normalize(v), normalize(n), dot(n, n) > 0.0);
    var out: FragmentOutput;
    if colour_mode == 2u {
        out.color = vec4<f32>(n * 0.5 + 0.5, 1.0);
    } else {
        var base = abs(g.e1) * clamp(g.fa, 0.2, 1.0);
        if colour_mode == 1u {
            base = viridis(g.fa);
        }
        out.color = vec4<f32>(headlight(base, n, ray.dir, params.ambient), 1.0);
    }
    out.depth = depth_of(view.clip_from_world, g.centre + v);
    return out;
}
