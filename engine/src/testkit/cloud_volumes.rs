//! Procedural test volumes for the cloud pipeline: a cumulus-like cloud (SPEC §3 input welcomes
//! generated volumes; no real atmospheric cloud is in `shared/data`) and the ambient edit's
//! standard painted regions on it. Used by the tests and the benchmarks, so both measure the
//! same cloud.

use crate::geom::Volume;

/// Procedural cumulus: a few overlapping spheres with fBm-perturbed edges, flat base.
pub fn cumulus(n: usize) -> Volume {
    let hash = |x: i32, y: i32, z: i32| -> f32 {
        let mut h = (x as u32).wrapping_mul(0x8da6_b343)
            ^ (y as u32).wrapping_mul(0xd816_3841)
            ^ (z as u32).wrapping_mul(0xcb1a_b31f);
        h ^= h >> 13;
        h = h.wrapping_mul(0x5bd1_e995);
        h ^= h >> 15;
        (h & 0xffff) as f32 / 65535.0
    };
    let noise = |p: [f32; 3]| -> f32 {
        let i = p.map(|v| v.floor() as i32);
        let f = [0, 1, 2].map(|k| {
            let t = p[k] - p[k].floor();
            t * t * (3.0 - 2.0 * t)
        });
        let mut s = 0.0;
        for c in 0..8 {
            let (a, b, e) = (c & 1, (c >> 1) & 1, (c >> 2) & 1);
            let w = (if a == 1 { f[0] } else { 1.0 - f[0] })
                * (if b == 1 { f[1] } else { 1.0 - f[1] })
                * (if e == 1 { f[2] } else { 1.0 - f[2] });
            s += w * hash(i[0] + a, i[1] + b, i[2] + e);
        }
        s
    };
    let spheres = [
        ([0.5, 0.35, 0.5], 0.22),
        ([0.33, 0.3, 0.45], 0.16),
        ([0.67, 0.3, 0.55], 0.17),
        ([0.48, 0.52, 0.5], 0.16),
    ];
    let mut d = Vec::with_capacity(n * n * n);
    for z in 0..n {
        for y in 0..n {
            for x in 0..n {
                let p = [x, y, z].map(|v| (v as f32 + 0.5) / n as f32);
                let mut fbm = 0.0;
                let mut amp = 0.5;
                let mut fr = 6.0;
                for _ in 0..4 {
                    fbm += amp * noise(p.map(|v| v * fr));
                    amp *= 0.5;
                    fr *= 2.0;
                }
                let mut field = f32::NEG_INFINITY;
                for (c, r) in spheres {
                    let dd =
                        ((p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2) + (p[2] - c[2]).powi(2))
                            .sqrt();
                    field = field.max(1.0 - dd / r);
                }
                let base = ((p[1] - 0.18) * 20.0).clamp(0.0, 1.0);
                let v = ((field + 0.35 * (fbm - 0.45)) * 3.0).clamp(0.0, 1.0) * base;
                d.push(v);
            }
        }
    }
    // Every value is finite and in [0, 1] by construction.
    Volume {
        dims: [n; 3],
        density: d,
        bounds: Volume::default_bounds([n; 3]),
    }
}

/// Two painted regions of cloud voxels on a [`cumulus`] (warm on the left, cool on the right),
/// as (voxel index, linear RGB) pins for the ambient propagation (§3.2).
pub fn cumulus_pins(v: &Volume) -> Vec<(usize, [f32; 3])> {
    let n = v.dims;
    let mut pins = vec![];
    for z in 0..n[2] {
        for y in 0..n[1] {
            for x in 0..n[0] {
                let i = v.index(x, y, z);
                if v.density[i] <= 0.0 {
                    continue;
                }
                let p = [
                    x as f64 / n[0] as f64,
                    y as f64 / n[1] as f64,
                    z as f64 / n[2] as f64,
                ];
                let d1 = (p[0] - 0.35).powi(2) + (p[1] - 0.3).powi(2) + (p[2] - 0.45).powi(2);
                let d2 = (p[0] - 0.65).powi(2) + (p[1] - 0.4).powi(2) + (p[2] - 0.55).powi(2);
                if d1 < 0.004 {
                    pins.push((i, [0.9, 0.5, 0.3]));
                } else if d2 < 0.003 {
                    pins.push((i, [0.2, 0.3, 0.8]));
                }
            }
        }
    }
    pins
}
