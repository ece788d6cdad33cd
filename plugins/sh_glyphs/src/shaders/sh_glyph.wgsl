// Ray-cast SH glyphs (SEEDS.md section 4): the surface r = s(psi(u)) around each glyph centre, s = max(., 0)
// or |.|, drawn per pixel on the glyph's box proxy, no tessellation. Two methods find the first hit:
//
// exact (after Peters et al., VMV 2023): the plane through the glyph centre and the ray cuts the glyph along
// r = s(psi(theta)), psi a trigonometric polynomial of degree k = l_max on that great circle, known exactly
// from k + 1 evaluations of psi; the ray is r = b / cos(theta), so the hits are the roots of the
// trigonometric polynomial g = s(psi(theta)) cos(theta) - b (degree k + 1). On the ray's span inside the
// glyph's box, steps in theta of -g / Lambda (Lambda a Lipschitz constant of g: no root is skipped) and at
// least span / (4 `samples`) bracket the first root, `refine` bisections in t refine it. Coordinates are in
// units of the glyph's render bound. f64 twin: `fascicle_core::sh::exact::cast_poly`.
//
// linear (the seed's): the ray meets the sphere of the render bound on [t0, t1]; march from t0 in steps of
// h * rbound until F(p) = |p - c| - s(psi(u)) < 0, then bisect. f64 twin: `fascicle_core::sh::glyph::cast`.
//
// Normal: grad F = u - s'(psi) (I - u u^T) grad g / r (analytic). Headlight shading, true fragment depth.
// Keep `GlyphParams` in sync with `ShGlyphUniform` in `plugins/sh_glyphs/src/lib.rs`.

#import fascicle::proxy::{ProxyVertex, ProxyVertexOutput, proxy_glyph, proxy_vertex}
#import bevy_pbr::mesh_view_bindings::view
#import fascicle::ray::{Ray, view_ray, depth_of, sphere_interval}
#import fascicle::lighting::headlight
#import fascicle::colormap::viridis

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
    // 0: linear search, 1: exact (polynomial form)
    method: u32,
    samples: u32,
    // Phong specular weight of the headlight (exponent 32).
    specular: f32,
};

@group(#{MATERIAL_BIND_GROUP}) @binding(0) var<uniform> params: GlyphParams;
// Per glyph, three entries: (centre (world, mm), render bound), (GFA, highlighted, 0, 0), (box half extents, 0).
@group(#{MATERIAL_BIND_GROUP}) @binding(1) var<storage, read> glyphs: array<vec4<f32>>;
// Per glyph, `stride` numbers: its coefficients (glyph basis) in the Chebyshev form described below.
@group(#{MATERIAL_BIND_GROUP}) @binding(2) var<storage, read> coeffs: array<f32>;

// psi on the sphere from the glyph's internal form (`fascicle_core::sh::glyph::chebyshev_form`, made on
// upload): psi(u) = sum over m of Re((x + iy)^m) A_m(z) + Im((x + iy)^m) B_m(z), where A_m and B_m are
// z^(m mod 2) times a Chebyshev series in w = 2z^2 - 1 of (l_max - m) / 2 + 1 terms, band by band, A then B
// (no B for m = 0). Clenshaw's recurrence costs two operations per stored number; the Legendre recurrence
// it replaced cost a dozen per (l, m), and the form stays accurate in f32 (a power basis would not). The
// numbers are read from the glyph's slice of `coeffs` where used: no per-fragment copy into a private
// array, which a software rasteriser keeps in memory. f64 twin: `eval_chebyshev_form`.

// Twelve directions at once, as three vec4 (the exact method's samples): each stored number is read once
// for all twelve. Arrays indexed only in loops of fixed length (unrolled: registers).
struct Dirs {
    x: array<vec4<f32>, 3>,
    y: array<vec4<f32>, 3>,
    z: array<vec4<f32>, 3>,
};

// The Chebyshev series at `at`, `nt` terms, at the twelve w.
fn clenshaw12(at: u32, nt: u32, w: array<vec4<f32>, 3>) -> array<vec4<f32>, 3> {
    var b1 = array<vec4<f32>, 3>(vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0));
    var b2 = b1;
    for (var j = nt - 1u; j > 0u; j--) {
        let cj = coeffs[at + j];
        for (var g = 0u; g < 3u; g++) {
            let b0 = 2.0 * w[g] * b1[g] - b2[g] + cj;
            b2[g] = b1[g];
            b1[g] = b0;
        }
    }
    let c0 = coeffs[at];
    var out: array<vec4<f32>, 3>;
    for (var g = 0u; g < 3u; g++) {
        out[g] = w[g] * b1[g] - b2[g] + c0;
    }
    return out;
}

// psi at twelve unit directions, the glyph's form from `first`.
fn sh_value12(first: u32, l_max: u32, d: Dirs) -> array<vec4<f32>, 3> {
    var w: array<vec4<f32>, 3>;
    var cm: array<vec4<f32>, 3>;
    var sm: array<vec4<f32>, 3>;
    for (var g = 0u; g < 3u; g++) {
        w[g] = 2.0 * d.z[g] * d.z[g] - 1.0;
        cm[g] = vec4<f32>(1.0);
        sm[g] = vec4<f32>(0.0);
    }
    var val = clenshaw12(first, l_max / 2u + 1u, w);
    var at = first + l_max / 2u + 1u;
    for (var m = 1u; m <= l_max; m++) {
        let nt = (l_max - m) / 2u + 1u;
        let a = clenshaw12(at, nt, w);
        let b = clenshaw12(at + nt, nt, w);
        at += 2u * nt;
        for (var g = 0u; g < 3u; g++) {
            let c_new = cm[g] * d.x[g] - sm[g] * d.y[g];
            sm[g] = cm[g] * d.y[g] + sm[g] * d.x[g];
            cm[g] = c_new;
            let odd = select(vec4<f32>(1.0), d.z[g], m % 2u == 1u);
            val[g] += odd * (cm[g] * a[g] + sm[g] * b[g]);
        }
    }
    return val;
}

// The Chebyshev series at `at`, `nt` terms, at w (one direction).
fn clenshaw(at: u32, nt: u32, w: f32) -> f32 {
    var b1 = 0.0;
    var b2 = 0.0;
    for (var j = nt - 1u; j > 0u; j--) {
        let b0 = 2.0 * w * b1 - b2 + coeffs[at + j];
        b2 = b1;
        b1 = b0;
    }
    return w * b1 - b2 + coeffs[at];
}

// psi(u) for unit u (one direction: the linear search's step), as `sh_value12`.
fn sh_value(first: u32, l_max: u32, u: vec3<f32>) -> f32 {
    let w = 2.0 * u.z * u.z - 1.0;
    var val = clenshaw(first, l_max / 2u + 1u, w);
    var at = first + l_max / 2u + 1u;
    var cm = 1.0;
    var sm = 0.0;
    for (var m = 1u; m <= l_max; m++) {
        let c_new = cm * u.x - sm * u.y;
        sm = cm * u.y + sm * u.x;
        cm = c_new;
        let nt = (l_max - m) / 2u + 1u;
        let odd = select(1.0, u.z, m % 2u == 1u);
        val += odd * (cm * clenshaw(at, nt, w) + sm * clenshaw(at + nt, nt, w));
        at += 2u * nt;
    }
    return val;
}

// The Chebyshev series at `at` (nt terms) in w = 2z^2 - 1 times z^odd, and its derivative in z (g' as the
// series sum j c_j U_{j-1}(w)).
fn clenshaw_grad(at: u32, nt: u32, z: f32, odd: bool) -> vec2<f32> {
    let w = 2.0 * z * z - 1.0;
    var b1 = 0.0;
    var b2 = 0.0;
    var d1 = 0.0;
    var d2 = 0.0;
    for (var j = nt - 1u; j > 0u; j--) {
        let cj = coeffs[at + j];
        let b0 = 2.0 * w * b1 - b2 + cj;
        b2 = b1;
        b1 = b0;
        let d0 = 2.0 * w * d1 - d2 + f32(j) * cj;
        d2 = d1;
        d1 = d0;
    }
    let g = w * b1 - b2 + coeffs[at];
    let dg = d1 * 4.0 * z;
    return select(vec2<f32>(g, dg), vec2<f32>(z * g, g + z * dg), odd);
}

// (psi(u), gradient of the extension of psi at u). The surface gradient is the tangential part,
// grad - dot(grad, u) u.
fn sh_value_grad(first: u32, l_max: u32, u: vec3<f32>) -> vec4<f32> {
    let a0 = clenshaw_grad(first, l_max / 2u + 1u, u.z, false);
    var val = a0.x;
    var grad = vec3<f32>(0.0, 0.0, a0.y);
    var at = first + l_max / 2u + 1u;
    var cm = 1.0;
    var sm = 0.0;
    for (var m = 1u; m <= l_max; m++) {
        let cm1 = cm;
        let sm1 = sm;
        cm = cm1 * u.x - sm1 * u.y;
        sm = cm1 * u.y + sm1 * u.x;
        let nt = (l_max - m) / 2u + 1u;
        let odd = m % 2u == 1u;
        let a = clenshaw_grad(at, nt, u.z, odd);
        let b = clenshaw_grad(at + nt, nt, u.z, odd);
        at += 2u * nt;
        let mf = f32(m);
        val += cm * a.x + sm * b.x;
        grad.x += mf * (a.x * cm1 + b.x * sm1);
        grad.y += mf * (b.x * cm1 - a.x * sm1);
        grad.z += cm * a.y + sm * b.y;
    }
    return vec4<f32>(val, grad);
}

@vertex
fn vertex(v: ProxyVertex) -> ProxyVertexOutput {
    // Loop counts and modes reach the fragment stage flat (the rule in `fascicle::ray`); `Knobs` unpacks them.
    let modes = params.l_max | (params.lobes << 8u) | (params.colour_mode << 16u) | (params.method << 24u);
    // The last knob: the linear search's step count or the exact method's samples.
    let steps = select(params.max_steps, params.samples, params.method == 1u);
    // The glyph's box, scaled about its centre by the layer's size factor.
    let i = proxy_glyph(v);
    let half = glyphs[3u * i + 2u].xyz * params.size;
    return proxy_vertex(v, glyphs[3u * i].xyz, half, vec4<u32>(modes, params.stride, params.refine, steps));
}

struct Knobs {
    l_max: u32,
    lobes: u32,
    colour_mode: u32,
    method: u32,
    stride: u32,
    refine: u32,
    // Linear: the step count; exact: the samples.
    max_steps: u32,
};

fn knobs(k: vec4<u32>) -> Knobs {
    return Knobs(k.x & 0xffu, (k.x >> 8u) & 0xffu, (k.x >> 16u) & 0xffu, k.x >> 24u, k.y, k.z, k.w);
}

// The glyph's section by the plane through its centre and the ray: psi(theta) on that great circle as a
// trigonometric polynomial in phi = 2 theta (degree k / 2; even orders have only even frequencies), from
// k + 1 samples by a discrete Fourier transform. Twin of `fascicle_core::sh::exact::RayPlane`. The arrays
// hold the largest order's 9 frequencies and are only ever indexed by constants (loops of fixed length,
// zeros past `terms`), so that they live in registers: a software rasteriser runs every dynamically
// indexed private array through memory, one lane at a time.
struct RayPlane {
    b: f32,
    tc: f32,
    terms: u32,
    cs: array<f32, 9>,
    sn: array<f32, 9>,
};

// `tc` and `foot`: the parameter of the ray's closest point to the centre, and that point. The k + 1
// samples are evaluated twelve at a time (`sh_value12`: each stored number read once per twelve samples).
fn ray_plane(first: u32, scale: f32, k: u32, dir: vec3<f32>, tc: f32, foot: vec3<f32>) -> RayPlane {
    var rp: RayPlane;
    rp.tc = tc;
    rp.b = length(foot);
    var e = foot / rp.b;
    if !(rp.b > 0.0) {
        e = normalize(cross(dir, select(vec3<f32>(1.0, 0.0, 0.0), vec3<f32>(0.0, 1.0, 0.0), abs(dir.x) > 0.9)));
    }
    let n = k + 1u;
    rp.terms = k / 2u + 1u;
    for (var m = 0u; m < 9u; m++) {
        rp.cs[m] = 0.0;
        rp.sn[m] = 0.0;
    }
    let w = scale / f32(n);
    // Sample j at theta = j pi / n: four consecutive angles from a group's first by the angle-addition
    // formula, the first advanced by 4 pi / n per group (no trigonometry per sample).
    let delta = 3.14159265358979 / f32(n);
    let offsets = vec4<f32>(0.0, 1.0, 2.0, 3.0) * delta;
    let ck = cos(offsets);
    let sk = sin(offsets);
    let c4 = cos(4.0 * delta);
    let s4 = sin(4.0 * delta);
    var ca = 1.0;
    var sa = 0.0;
    for (var j0 = 0u; j0 < n; j0 += 12u) {
        var d: Dirs;
        var cts: array<vec4<f32>, 3>;
        var sts: array<vec4<f32>, 3>;
        for (var g = 0u; g < 3u; g++) {
            let ct = ca * ck - sa * sk;
            let st = sa * ck + ca * sk;
            let next = ca * c4 - sa * s4;
            sa = sa * c4 + ca * s4;
            ca = next;
            cts[g] = ct;
            sts[g] = st;
            d.x[g] = ct * e.x + st * dir.x;
            d.y[g] = ct * e.y + st * dir.y;
            d.z[g] = ct * e.z + st * dir.z;
        }
        let vals = sh_value12(first, k, d);
        for (var g = 0u; g < 3u; g++) {
            // Samples past k + 1 get weight 0.
            let j = vec4<u32>(j0 + 4u * g) + vec4<u32>(0u, 1u, 2u, 3u);
            let v = vals[g] * w * vec4<f32>(j < vec4<u32>(n));
            // cos(m phi), sin(m phi) by the angle-addition recurrence, phi = 2 theta.
            let ct = cts[g];
            let st = sts[g];
            let c1 = ct * ct - st * st;
            let s1 = 2.0 * st * ct;
            var cm = vec4<f32>(1.0);
            var sm = vec4<f32>(0.0);
            rp.cs[0] += v.x + v.y + v.z + v.w;
            for (var m = 1u; m < 9u; m++) {
                let cn = cm * c1 - sm * s1;
                sm = sm * c1 + cm * s1;
                cm = cn;
                // Frequencies past k / 2 are zero (exactly so for the samples of a degree-k polynomial).
                let keep = select(0.0, 2.0, m < rp.terms);
                rp.cs[m] += keep * dot(v, cm);
                rp.sn[m] += keep * dot(v, sm);
            }
        }
    }
    return rp;
}

// psi at phi = 2 theta from (cos phi, sin phi), by the angle-addition recurrence.
fn plane_psi(rp: ptr<function, RayPlane>, c1: f32, s1: f32) -> f32 {
    var cm = 1.0;
    var sm = 0.0;
    var psi = (*rp).cs[0];
    for (var m = 1u; m < 9u; m++) {
        let cn = cm * c1 - sm * s1;
        sm = sm * c1 + cm * s1;
        cm = cn;
        psi += (*rp).cs[m] * cm + (*rp).sn[m] * sm;
    }
    return psi;
}

// s(psi) - r at the ray's point t: positive inside the glyph. cos 2theta and sin 2theta are rational in t.
fn plane_inside(rp: ptr<function, RayPlane>, t: f32, lobes: u32) -> f32 {
    let tau = t - (*rp).tc;
    let b = (*rp).b;
    let r2 = tau * tau + b * b;
    var c1 = 1.0;
    var s1 = 0.0;
    if r2 > 0.0 {
        c1 = (b * b - tau * tau) / r2;
        s1 = 2.0 * b * tau / r2;
    }
    return shape(plane_psi(rp, c1, s1), lobes) - sqrt(r2);
}

// g(theta) = s(psi(theta)) cos(theta) - b: positive inside the glyph.
fn plane_section(rp: ptr<function, RayPlane>, theta: f32, lobes: u32) -> f32 {
    let s = sin(theta);
    let c = cos(theta);
    return shape(plane_psi(rp, c * c - s * s, 2.0 * s * c), lobes) * c - (*rp).b;
}

// A Lipschitz constant of g in theta: |psi| + |dpsi/dtheta| <= sum (1 + 2m)(|a_m| + |b_m|).
fn plane_lipschitz(rp: ptr<function, RayPlane>) -> f32 {
    var l = 0.0;
    for (var m = 0u; m < 9u; m++) {
        l += (1.0 + 2.0 * f32(m)) * (abs((*rp).cs[m]) + abs((*rp).sn[m]));
    }
    return l;
}

// Entry (clamped to 0) and exit distances of a unit ray through the box of half extents `half` about the
// origin (the ray's origin relative to the centre); y <= x means a miss. Twin of
// `fascicle_core::sh::exact::ray_box_interval`.
fn box_interval(oc: vec3<f32>, dir: vec3<f32>, half: vec3<f32>) -> vec2<f32> {
    let inv = 1.0 / dir;
    let a = (-half - oc) * inv;
    let b = (half - oc) * inv;
    let lo = min(a, b);
    let hi = max(a, b);
    let t0 = max(max(lo.x, lo.y), max(lo.z, 0.0));
    let t1 = min(min(hi.x, hi.y), hi.z);
    return vec2<f32>(t0, t1);
}

// The exact method: the first hit's distance along the ray (in the units of `oc`), or -1.
fn first_hit_exact(first: u32, scale: f32, oc: vec3<f32>, dir: vec3<f32>, half: vec3<f32>, cfg: Knobs) -> f32 {
    let span = box_interval(oc, dir, half);
    if span.y <= span.x {
        return -1.0;
    }
    // A ray farther from the centre than the render bound (1 in these units) misses: no psi evaluated.
    let tc = -dot(oc, dir);
    let foot = oc + tc * dir;
    if dot(foot, foot) > 1.0 {
        return -1.0;
    }
    var rp = ray_plane(first, scale, cfg.l_max, dir, tc, foot);
    let n = max(cfg.max_steps, 1u);
    var lo = span.x;
    var hi = span.x;
    if rp.b > 1e-4 {
        // Steps in theta of -g / Lambda (certified: no root closer), at least span / (4 samples).
        let th0 = atan2(span.x - rp.tc, rp.b);
        let th1 = atan2(span.y - rp.tc, rp.b);
        let lam = max(plane_lipschitz(&rp), 1e-30);
        let dmin = (th1 - th0) / (4.0 * f32(n));
        var th = th0;
        var th_lo = th0;
        var found = false;
        for (var i = 0u; i <= 64u * n; i++) {
            let g = plane_section(&rp, th, cfg.lobes);
            if g > 0.0 {
                found = true;
                break;
            }
            if th >= th1 {
                break;
            }
            th_lo = th;
            th = min(th + max(-g / lam, dmin), th1);
        }
        if !found {
            return -1.0;
        }
        lo = max(rp.tc + rp.b * tan(th_lo), span.x);
        hi = min(rp.tc + rp.b * tan(th), span.y);
        if plane_inside(&rp, lo, cfg.lobes) > 0.0 {
            return lo;
        }
        if !(plane_inside(&rp, hi, cfg.lobes) > 0.0) {
            return hi;
        }
    } else {
        // The ray meets the centre (theta is +-pi/2 on all of it): uniform samples in t.
        let step = (span.y - span.x) / f32(n);
        var found = plane_inside(&rp, span.x, cfg.lobes) > 0.0;
        for (var i = 1u; i <= n && !found; i++) {
            let t = span.x + step * f32(i);
            if plane_inside(&rp, t, cfg.lobes) > 0.0 {
                hi = t;
                found = true;
            } else {
                lo = t;
            }
        }
        if !found {
            return -1.0;
        }
    }
    for (var i = 0u; i < cfg.refine; i++) {
        let mid = 0.5 * (lo + hi);
        if plane_inside(&rp, mid, cfg.lobes) > 0.0 {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    return hi;
}

struct FragmentOutput {
    @location(0) color: vec4<f32>,
    @builtin(frag_depth) depth: f32,
};

fn shape(psi: f32, lobes: u32) -> f32 {
    return select(max(psi, 0.0), abs(psi), lobes == 1u);
}

// F(p) < 0 inside the glyph.
fn implicit(first: u32, scale: f32, v: vec3<f32>, cfg: Knobs) -> f32 {
    let r = length(v);
    if r <= 0.0 {
        return -1.0;
    }
    return r - shape(scale * sh_value(first, cfg.l_max, v / r), cfg.lobes);
}

@fragment
fn fragment(in: ProxyVertexOutput) -> FragmentOutput {
    let cfg = knobs(in.knobs);
    let g = glyphs[3u * in.tag];
    let centre = g.xyz;
    let rmax = g.w * params.size;
    // Exact: coefficients and coordinates in units of the render bound (|x| <= sqrt 3 in the box).
    let unit = select(1.0, 1.0 / rmax, cfg.method == 1u);
    // The coefficients are read where used, scaled by `scale` (psi is linear in them).
    let first = in.tag * cfg.stride;
    let scale = params.size * unit;
    let ray = view_ray(in.world_position, view.world_position, view.world_from_view, view.clip_from_view);
    // Work relative to the centre: the glyph is small next to its distance from the camera.
    let oc = ray.origin - centre;
    var hi = 0.0;
    if cfg.method == 1u {
        let half = glyphs[3u * in.tag + 2u].xyz * params.size * unit;
        let t = first_hit_exact(first, scale, oc * unit, ray.dir, half, cfg);
        if t < 0.0 {
            discard;
        }
        hi = t / unit;
    } else {
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
            if implicit(first, scale, oc + t * ray.dir, cfg) < 0.0 {
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
        hi = t;
        for (var k = 0u; k < cfg.refine; k++) {
            let mid = 0.5 * (lo + hi);
            if implicit(first, scale, oc + mid * ray.dir, cfg) < 0.0 {
                hi = mid;
            } else {
                lo = mid;
            }
        }
    }
    let v = oc + hi * ray.dir;
    let r = max(length(v), 1e-20);
    let u = v / r;
    // The normal's tangential term is psi's gradient over r, r in world units: undo the exact method's unit.
    let pg = scale * sh_value_grad(first, cfg.l_max, u) / vec4<f32>(1.0, unit, unit, unit);
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
        base = viridis(glyphs[3u * in.tag + 1u].x);
    }
    var out: FragmentOutput;
    if cfg.colour_mode == 1u {
        out.color = vec4<f32>(base, 1.0);
    } else {
        var shaded = headlight(base, n, ray.dir, params.ambient);
        // Phong with a headlight: the reflected light returns along the view ray where n faces the eye.
        shaded += vec3<f32>(params.specular * pow(max(dot(n, -ray.dir), 0.0), 32.0));
        if cfg.lobes == 1u && pg.x < 0.0 {
            // Negative lobes: desaturated, as mrview marks them.
            shaded = vec3<f32>(dot(shaded, vec3<f32>(0.3, 0.4, 0.3))) * 0.6;
        }
        if glyphs[3u * in.tag + 1u].y > 0.5 {
            // Picked: tinted towards yellow.
            shaded = mix(shaded, vec3<f32>(1.0, 0.85, 0.1), 0.6);
        }
        out.color = vec4<f32>(shaded, 1.0);
    }
    out.depth = depth_of(view.clip_from_world, centre + v);
    return out;
}
