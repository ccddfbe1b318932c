//! Unit checks of the hierarchy's pieces against their definitions.

use super::aggregate::Prolongation;
use super::fine::fine_level;
use super::graph::Rgb;
use super::graph::{Adjacency, Graph};
use super::*;

/// A deterministic pseudo-random value in [0, 1).
fn rnd(i: usize, salt: u32) -> f32 {
    let mut h = (i as u32).wrapping_mul(0x9e37_79b9) ^ salt.wrapping_mul(0x85eb_ca6b);
    h ^= h >> 15;
    h = h.wrapping_mul(0x2c1b_3c6d);
    h ^= h >> 12;
    (h & 0xffff) as f32 / 65536.0
}

/// The fine level of a random guide with 5 % of the voxels pinned, every voxel in the cloud.
fn random_fine(dims: [usize; 3]) -> Graph {
    let n = dims[0] * dims[1] * dims[2];
    let guide: Vec<f32> = (0..n).map(|i| rnd(i, 1)).collect();
    let a = llw_weights(dims, &guide);
    let pin_at: Vec<u32> = (0..n)
        .map(|i| if rnd(i, 2) < 0.05 { 0 } else { u32::MAX })
        .collect();
    fine_level(dims, &a, &vec![true; n], &pin_at, &[[1.0, 0.5, 0.0]], 0.0).op
}

/// `A e` of any level through its adjacency (f64).
fn apply_rows<A: Adjacency>(a: &A, e: &[Rgb]) -> Vec<[f64; 3]> {
    (0..a.len())
        .map(|i| {
            let mut v = [0f64; 3];
            for q in 0..3 {
                v[q] = f64::from(a.excess(i)) * f64::from(e[i][q]);
            }
            a.each(i, |j, c| {
                for q in 0..3 {
                    v[q] += f64::from(c) * f64::from(e[i][q] - e[j][q]);
                }
            });
            v
        })
        .collect()
}

/// Checks `c = Pᵀ A P` on random coarse vectors, symmetry and the colouring.
fn check_galerkin<A: Adjacency>(a: &A, p: &Prolongation, c: &Graph, what: &str) {
    let nc = c.len();
    let vc: Vec<Rgb> = (0..nc).map(|i| [rnd(i, 3), rnd(i, 4), rnd(i, 5)]).collect();
    let mut pv = vec![[0f32; 3]; a.len()];
    p.prolong_add(&vc, &mut pv);
    let apv: Vec<Rgb> = apply_rows(a, &pv)
        .iter()
        .map(|v| v.map(|x| x as f32))
        .collect();
    let mut want = vec![[0f32; 3]; nc];
    p.restrict(&apv, &mut want);
    let got = apply_rows(c, &vc);
    for i in 0..nc {
        for q in 0..3 {
            let (w, g) = (f64::from(want[i][q]), got[i][q]);
            assert!(
                (w - g).abs() < 1e-4 * (1.0 + w.abs()),
                "{what} {i}: {w} vs {g}"
            );
        }
    }
    for i in 0..nc {
        c.each(i, |j, cij| {
            let mut back = None;
            c.each(j, |k, cji| {
                if k == i {
                    back = Some(cji);
                }
            });
            let cji = back.expect("symmetric pattern");
            assert!(
                (cij - cji).abs() <= 1e-5 * cij.abs().max(1e-3),
                "{what}: {cij} {cji}"
            );
        });
    }
    for k in 0..c.colors.len() - 1 {
        for i in c.colors[k]..c.colors[k + 1] {
            c.each(i, |j, _| assert!(j < c.colors[k] || j >= c.colors[k + 1]));
        }
    }
}

#[test]
fn galerkin_levels_are_pt_a_p() {
    let fine = random_fine([20, 18, 16]);
    let (p1, c1) = coarsen(&fine, THETA, None);
    check_galerkin(&fine, &p1, &c1, "level 1");
    let (p2, c2) = coarsen(&c1, THETA, None);
    check_galerkin(&c1, &p2, &c2, "level 2");
}

#[test]
fn galerkin_operator_is_pt_a_p_and_symmetric() {
    for dims in [[7, 6, 5], [12, 9, 10]] {
        let fine = random_fine(dims);
        let (p, c) = coarsen(&fine, THETA, None);
        let nc = c.len();
        assert!(nc < fine.len() / 2, "{dims:?}: {nc} coarse points");
        let vc: Vec<Rgb> = (0..nc).map(|i| [rnd(i, 3), rnd(i, 4), rnd(i, 5)]).collect();
        let mut pv = vec![[0f32; 3]; fine.len()];
        p.prolong_add(&vc, &mut pv);
        let apv: Vec<Rgb> = apply_rows(&fine, &pv)
            .iter()
            .map(|v| v.map(|x| x as f32))
            .collect();
        let mut want = vec![[0f32; 3]; nc];
        p.restrict(&apv, &mut want);
        let got = apply_rows(&c, &vc);
        for i in 0..nc {
            for q in 0..3 {
                let (w, g) = (f64::from(want[i][q]), got[i][q]);
                assert!(
                    (w - g).abs() < 1e-4 * (1.0 + w.abs()),
                    "{dims:?} {i}: {w} vs {g}"
                );
            }
        }
        // Symmetric: c_IJ = c_JI.
        for i in 0..nc {
            c.each(i, |j, cij| {
                let mut back = None;
                c.each(j, |k, cji| {
                    if k == i {
                        back = Some(cji);
                    }
                });
                let cji = back.expect("symmetric pattern");
                assert!(
                    (cij - cji).abs() <= 1e-5 * cij.abs().max(1e-3),
                    "{cij} {cji}"
                );
            });
        }
        // Colours: no conductance inside a colour range.
        for k in 0..c.colors.len() - 1 {
            for i in c.colors[k]..c.colors[k + 1] {
                c.each(i, |j, _| assert!(j < c.colors[k] || j >= c.colors[k + 1]));
            }
        }
    }
}

fn uniform_rates(dims: [usize; 3], pins: &[(usize, [f32; 3])]) -> Vec<f64> {
    let n = dims[0] * dims[1] * dims[2];
    let guide = vec![0.5f32; n];
    let (_, st) = propagate(
        dims,
        &guide,
        None,
        pins,
        &|_| [0.0; 3],
        SolveOptions::default(),
        &crate::NoControl,
    )
    .unwrap();
    assert!(
        *st.residuals.last().unwrap() <= 1e-6,
        "{dims:?}: {:?}",
        st.residuals
    );
    st.residuals.windows(2).map(|w| w[0] / w[1]).collect()
}

#[test]
fn uniform_guide_converges_fast() {
    // A constant guide: the plain graph Laplacian, with two pinned planes and with two small
    // pinned balls; odd and even sizes (aggregates meet the far faces differently).
    for n in [17usize, 24] {
        let idx = |x: usize, y: usize, z: usize| x + n * (y + n * z);
        let mut planes = vec![];
        let mut balls = vec![];
        for z in 0..n {
            for y in 0..n {
                planes.push((idx(0, y, z), [1.0, 0.0, 0.0]));
                planes.push((idx(n - 1, y, z), [0.0, 0.0, 1.0]));
                for x in 0..n {
                    let d = |c: [usize; 3]| {
                        [x, y, z]
                            .iter()
                            .zip(c)
                            .map(|(&p, q)| (p as f64 - q as f64).powi(2))
                            .sum::<f64>()
                    };
                    if d([5, 5, 5]) < 6.0 {
                        balls.push((idx(x, y, z), [1.0, 0.0, 0.0]));
                    } else if d([n - 6, n - 5, n - 7]) < 6.0 {
                        balls.push((idx(x, y, z), [0.0, 0.0, 1.0]));
                    }
                }
            }
        }
        for pins in [&planes, &balls] {
            let rates = uniform_rates([n; 3], pins);
            assert!(rates.iter().all(|&r| r >= 5.0), "{n}: {rates:?}");
        }
    }
}

#[test]
fn tiny_and_flat_grids_solve() {
    // Grids small enough to be the coarsest level themselves, and a single plane.
    for dims in [[3, 2, 2], [1, 1, 5], [40, 30, 1]] {
        let n = dims[0] * dims[1] * dims[2];
        let guide: Vec<f32> = (0..n).map(|i| rnd(i, 9)).collect();
        let pins = vec![(0, [1.0, 0.5, 0.0]), (n - 1, [0.0, 0.5, 1.0])];
        let (u, st) = propagate(
            dims,
            &guide,
            None,
            &pins,
            &|_| [0.0; 3],
            SolveOptions::default(),
            &crate::NoControl,
        )
        .unwrap();
        assert!(
            *st.residuals.last().unwrap() <= 1e-6,
            "{dims:?}: {:?}",
            st.residuals
        );
        assert_eq!(u[0], [1.0, 0.5, 0.0]);
        for c in &u {
            assert!(
                c.iter().all(|v| (-1e-4..=1.0 + 1e-4).contains(v)),
                "{dims:?}: {c:?}"
            );
        }
    }
}
