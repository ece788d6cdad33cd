// Real symmetric spherical harmonics in Cartesian form (no trigonometry, nothing singular at the poles):
// the basis is tournier07 non-legacy (plain orthonormal real SH, Condon-Shortley phase), coefficient j of
// (l even, m) at l(l+1)/2 + m. The f64 twin, tested against the trigonometric evaluation, is
// `fascicle_core::sh::glyph::eval_cartesian`; keep the two in step.
#define_import_path fascicle::sh

// Coefficients of l_max 16, the largest order the glyph shader supports.
const SH_MAX_COEFFS: u32 = 153u;
const SH_INV_4PI: f32 = 0.07957747154594767;
const SH_SQRT2: f32 = 1.4142135623730951;

// psi(u) for unit u.
fn sh_value(c: ptr<function, array<f32, 153>>, l_max: u32, u: vec3<f32>) -> f32 {
    var val = 0.0;
    var cm = 1.0;
    var sm = 0.0;
    var prod = 1.0;
    for (var m = 0u; m <= l_max; m++) {
        if m > 0u {
            prod *= f32(2u * m - 1u) / f32(2u * m);
            let c_new = cm * u.x - sm * u.y;
            sm = cm * u.y + sm * u.x;
            cm = c_new;
        }
        let sign = select(-1.0, 1.0, m % 2u == 0u);
        let mf = f32(m);
        var q2 = 0.0;
        var q1 = sign * sqrt(f32(2u * m + 1u) * SH_INV_4PI * prod);
        for (var l = m; l <= l_max; l++) {
            var q = q1;
            if l == m + 1u {
                q = sqrt(f32(2u * m + 3u)) * u.z * q1;
            } else if l > m + 1u {
                let lf = f32(l);
                let a = sqrt((4.0 * lf * lf - 1.0) / (lf * lf - mf * mf));
                let b = sqrt(((lf - 1.0) * (lf - 1.0) - mf * mf) / (4.0 * (lf - 1.0) * (lf - 1.0) - 1.0));
                q = a * (u.z * q1 - b * q2);
            }
            if l > m {
                q2 = q1;
                q1 = q;
            }
            if l % 2u == 0u {
                let base = l * (l + 1u) / 2u;
                if m == 0u {
                    val += (*c)[base] * q;
                } else {
                    val += SH_SQRT2 * q * ((*c)[base + m] * cm + (*c)[base - m] * sm);
                }
            }
        }
    }
    return val;
}

// (psi(u), gradient of the Cartesian polynomial extension of psi at u). The surface gradient is the
// tangential part, grad - dot(grad, u) u.
fn sh_value_grad(c: ptr<function, array<f32, 153>>, l_max: u32, u: vec3<f32>) -> vec4<f32> {
    var val = 0.0;
    var grad = vec3<f32>(0.0);
    var cm = 1.0;
    var sm = 0.0;
    var cm1 = 0.0;
    var sm1 = 0.0;
    var prod = 1.0;
    for (var m = 0u; m <= l_max; m++) {
        if m > 0u {
            prod *= f32(2u * m - 1u) / f32(2u * m);
            let c_new = cm * u.x - sm * u.y;
            let s_new = cm * u.y + sm * u.x;
            cm1 = cm;
            sm1 = sm;
            cm = c_new;
            sm = s_new;
        }
        let sign = select(-1.0, 1.0, m % 2u == 0u);
        let mf = f32(m);
        var q2 = 0.0;
        var q1 = sign * sqrt(f32(2u * m + 1u) * SH_INV_4PI * prod);
        var d2 = 0.0;
        var d1 = 0.0;
        for (var l = m; l <= l_max; l++) {
            var q = q1;
            var dq = 0.0;
            if l == m + 1u {
                let f = sqrt(f32(2u * m + 3u));
                q = f * u.z * q1;
                dq = f * q1;
            } else if l > m + 1u {
                let lf = f32(l);
                let a = sqrt((4.0 * lf * lf - 1.0) / (lf * lf - mf * mf));
                let b = sqrt(((lf - 1.0) * (lf - 1.0) - mf * mf) / (4.0 * (lf - 1.0) * (lf - 1.0) - 1.0));
                q = a * (u.z * q1 - b * q2);
                dq = a * (q1 + u.z * d1 - b * d2);
            }
            if l > m {
                q2 = q1;
                q1 = q;
                d2 = d1;
                d1 = dq;
            }
            if l % 2u == 0u {
                let base = l * (l + 1u) / 2u;
                if m == 0u {
                    let k = (*c)[base];
                    val += k * q;
                    grad.z += k * dq;
                } else {
                    let kc = SH_SQRT2 * (*c)[base + m];
                    let ks = SH_SQRT2 * (*c)[base - m];
                    val += q * (kc * cm + ks * sm);
                    grad.x += q * mf * (kc * cm1 + ks * sm1);
                    grad.y += q * mf * (ks * cm1 - kc * sm1);
                    grad.z += dq * (kc * cm + ks * sm);
                }
            }
        }
    }
    return vec4<f32>(val, grad);
}
