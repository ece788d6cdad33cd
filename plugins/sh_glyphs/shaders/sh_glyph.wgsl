// Ray-cast SH glyphs (SEEDS.md section 4): the surface r = s(psi(u)) around each glyph centre, s = max(., 0)
// or |.|, drawn per pixel on a bounding cube proxy, no tessellation.
//
// Per fragment: the view ray meets the bounding sphere of radius rmax (Cauchy-Schwarz bound) on
// [t0, t1]; march from t0 in steps of h * rmax until F(p) = |p - c| - s(psi(u)) < 0, then bisect `refine`
// times between the last outside and first inside point; discard if no inside point is found. Normal:
// grad F = u - s'(psi) (I - u u^T) grad g / r (analytic). Headlight shading, true fragment depth.
// The f64 twin of this algorithm is `fascicle_core::sh::glyph::cast`. Keep `GlyphParams` in sync with
// `ShGlyphUniform` in `plugins/sh_glyphs/src/lib.rs`.

#import fascicle::proxy::{ProxyVertex, ProxyVertexOutput, proxy_vertex_scaled}
#import bevy_pbr::mesh_view_bindings::view
#import fascicle::ray::{Ray, view_ray, depth_of, sphere_interval}
#import fascicle::lighting::headlight
#import fascicle::colormap::viridis
#import fascicle::sh::{sh_value, sh_value_grad}

struct GlyphParams {
    l_max: u32,
    stride: u32,
    refine: u32,
    // 0: clamp negative lobes, 1: |psi| with negative lobes marked
    lobes: u32,
    h: f32,
    ambient: f32,
    // 0: direction RGB, 1: normal as colour (tests), 2: flat grey, 3: GFA through viridis
    colour_mode: u32,
    max_steps: u32,
    // Layer-wide size factor: psi and the render bound are multiplied by it (a style edit, no re-upload).
    size: f32,
    _pad0: f32,
    _pad1: f32,
    _pad2: f32,
};

@group(#{MATERIAL_BIND_GROUP}) @binding(0) var<uniform> params: GlyphParams;
// Per glyph, two entries: (centre (world, mm), render bound), (GFA, highlighted, 0, 0).
@group(#{MATERIAL_BIND_GROUP}) @binding(1) var<storage, read> glyphs: array<vec4<f32>>;
// Per glyph, `stride` coefficients in the glyph basis.
@group(#{MATERIAL_BIND_GROUP}) @binding(2) var<storage, read> coeffs: array<f32>;

@vertex
fn vertex(v: ProxyVertex) -> ProxyVertexOutput {
    // Loop counts and modes reach the fragment stage flat (the rule in `fascicle::ray`); `Knobs` unpacks them.
    let modes = params.l_max | (params.lobes << 8u) | (params.colour_mode << 16u);
    return proxy_vertex_scaled(v, vec4<u32>(modes, params.stride, params.refine, params.max_steps), params.size);
}

struct Knobs {
    l_max: u32,
    lobes: u32,
    colour_mode: u32,
    stride: u32,
    refine: u32,
    max_steps: u32,
};

fn knobs(k: vec4<u32>) -> Knobs {
    return Knobs(k.x & 0xffu, (k.x >> 8u) & 0xffu, k.x >> 16u, k.y, k.z, k.w);
}

struct FragmentOutput {
    @location(0) color: vec4<f32>,
    @builtin(frag_depth) depth: f32,
};

fn shape(psi: f32, lobes: u32) -> f32 {
    return select(max(psi, 0.0), abs(psi), lobes == 1u);
}

// F(p) < 0 inside the glyph.
fn implicit(c: ptr<function, array<f32, 153>>, v: vec3<f32>, cfg: Knobs) -> f32 {
    let r = length(v);
    if r <= 0.0 {
        return -1.0;
    }
    return r - shape(sh_value(c, cfg.l_max, v / r), cfg.lobes);
}

@fragment
fn fragment(in: ProxyVertexOutput) -> FragmentOutput {
    let cfg = knobs(in.knobs);
    let g = glyphs[2u * in.tag];
    let centre = g.xyz;
    let rmax = g.w * params.size;
    var c: array<f32, 153>;
    let first = in.tag * cfg.stride;
    for (var j = 0u; j < cfg.stride; j++) {
        c[j] = coeffs[first + j] * params.size;
    }
    let ray = view_ray(in.world_position, view.world_position, view.world_from_view, view.clip_from_view);
    // Work relative to the centre: the glyph is small next to its distance from the camera.
    let oc = ray.origin - centre;
    let span = sphere_interval(oc, ray.dir, rmax);
    if span.y <= 0.0 {
        discard;
    }
    let t0 = span.x;
    let t1 = span.y;
    let step = max(params.h, 1e-4) * rmax;
    var lo = t0;
    var t = t0;
    var inside = false;
    for (var i = 0u; i < cfg.max_steps; i++) {
        if implicit(&c, oc + t * ray.dir, cfg) < 0.0 {
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
    for (var k = 0u; k < cfg.refine; k++) {
        let mid = 0.5 * (lo + hi);
        if implicit(&c, oc + mid * ray.dir, cfg) < 0.0 {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    let v = oc + hi * ray.dir;
    let r = max(length(v), 1e-20);
    let u = v / r;
    let pg = sh_value_grad(&c, cfg.l_max, u);
    let sgn = select(1.0, sign(pg.x), cfg.lobes == 1u);
    let tangential = pg.yzw - dot(pg.yzw, u) * u;
    var n = u - sgn * tangential / r;
    n = select(u, normalize(n), dot(n, n) > 0.0);
    var base = abs(u);
    if cfg.colour_mode == 1u {
        base = n * 0.5 + 0.5;
    } else if cfg.colour_mode == 2u {
        base = vec3<f32>(0.8);
    } else if cfg.colour_mode == 3u {
        base = viridis(glyphs[2u * in.tag + 1u].x);
    }
    var out: FragmentOutput;
    if cfg.colour_mode == 1u {
        out.color = vec4<f32>(base, 1.0);
    } else {
        var shaded = headlight(base, n, ray.dir, params.ambient);
        if cfg.lobes == 1u && pg.x < 0.0 {
            // Negative lobes: desaturated, as mrview marks them.
            shaded = vec3<f32>(dot(shaded, vec3<f32>(0.3, 0.4, 0.3))) * 0.6;
        }
        if glyphs[2u * in.tag + 1u].y > 0.5 {
            // Picked: tinted towards yellow.
            shaded = mix(shaded, vec3<f32>(1.0, 0.85, 0.1), 0.6);
        }
        out.color = vec4<f32>(shaded, 1.0);
    }
    out.depth = depth_of(view.clip_from_world, centre + v);
    return out;
}
