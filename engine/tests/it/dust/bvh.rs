//! The exposure rays' BVH on real models that broke obvhs 0.4's assumptions (issue 18): the
//! Sweet Home 3D cartoon biplane (a CWBVH deeper than the 32-entry traversal stack) and the
//! Khronos 2CylinderEngine (millimetre coordinates: quantised child boxes 1.5·10⁻⁵ outside their
//! parent, beyond `validate()`'s absolute 10⁻⁵). These tests run with debug assertions (the
//! test profile), so obvhs's own `validate()` runs on every tree built here
//! ([`phenomena_engine::geom::bvh::build`]); they also check the tree against brute force.

use glam::Vec3A;
use obvhs::cwbvh::bvh2_to_cwbvh::bvh2_to_cwbvh;
use obvhs::ray::Ray;
use obvhs::triangle::Triangle;
use phenomena_engine::dust::amount::{hemisphere_directions, ExposureScene};
use phenomena_engine::dust::{self, DustParams};
use phenomena_engine::geom::bvh::{balanced_bvh2, cwbvh_depth, RayScene, CWBVH_STACK};
use phenomena_engine::geom::mesh::Mesh;
use phenomena_engine::params::Limits;
use phenomena_engine::NoControl;
use serde_json::json;

use crate::render::materials::{read_with_sidecars, test_data};

fn decode(rel: &str) -> Mesh {
    let path = test_data(rel);
    let p = DustParams::from_json(&json!({}), &Limits::default()).unwrap();
    let (bytes, side) = read_with_sidecars(&path);
    let name = path.file_name().unwrap().to_str().unwrap();
    dust::run::decode(&bytes, Some(name), &side, &p, &Limits::default()).unwrap()
}

/// Whether the ray hits none of `tris` (brute force).
fn brute_escapes(tris: &[Triangle], o: Vec3A, d: Vec3A) -> bool {
    let ray = Ray::new_inf(o, d);
    tris.iter().all(|t| !t.intersect(&ray).is_finite())
}

fn world_triangles(mesh: &Mesh) -> Vec<[Vec3A; 3]> {
    let v = |i: u32| Vec3A::from_array(mesh.positions[i as usize]);
    mesh.triangles
        .iter()
        .map(|t| [v(t[0]), v(t[1]), v(t[2])])
        .collect()
}

/// Builds the scene (obvhs's `validate()` runs in this debug build), checks its depth, and casts
/// rays from points just off the surface over the hemisphere above them: the BVH's answer equals
/// brute force's (a traversal-stack overflow loses whole subtrees: rays that should hit, miss).
fn check_model(rel: &str) {
    let mesh = decode(rel);
    let exposure = ExposureScene::new(&mesh);
    assert!(
        exposure.depth() < CWBVH_STACK,
        "{rel}: depth {}",
        exposure.depth()
    );
    let world = world_triangles(&mesh);
    let scene = RayScene::new(world.iter().copied());
    assert!(scene.depth() < CWBVH_STACK);
    let tris: Vec<Triangle> = world
        .iter()
        .map(|&[v0, v1, v2]| Triangle { v0, v1, v2 })
        .collect();
    let (lo, hi) = mesh.bounds().unwrap();
    let diag = (Vec3A::from_array(hi) - Vec3A::from_array(lo)).length();
    let dirs = hemisphere_directions([0.0, 1.0, 0.0], 8);
    let (mut rays, mut mismatches, mut hits) = (0usize, 0usize, 0usize);
    let step = (mesh.triangles.len() / 60).max(1);
    for t in mesh.triangles.iter().step_by(step) {
        let [a, b, c] = t.map(|i| Vec3A::from_array(mesh.positions[i as usize]));
        let n = (b - a).cross(c - a);
        if n.length_squared() == 0.0 {
            continue;
        }
        let o = (a + b + c) / 3.0 + n.normalize() * 1e-4 * diag;
        for d in &dirs {
            let d = Vec3A::from_array(*d);
            let brute = brute_escapes(&tris, o, d);
            rays += 1;
            hits += usize::from(!brute);
            mismatches += usize::from(scene.escapes(o, d) != brute);
        }
    }
    eprintln!(
        "{rel}: {} triangles, depth {}, {rays} rays, {hits} hit, {mismatches} differ from brute force",
        scene.len(),
        scene.depth()
    );
    assert!(
        hits > rays / 20,
        "{rel}: the rays meet the model ({hits} of {rays})"
    );
    // Only rays that graze an edge may differ (the scene is rescaled to the unit box, which
    // rounds the vertices differently).
    assert!(
        mismatches * 200 <= rays,
        "{rel}: {mismatches} of {rays} rays differ from brute force"
    );
}

#[test]
fn cartoon_biplane_builds_a_valid_bvh_within_the_traversal_stack() {
    check_model("mesh/cartoon_biplane/cartoon_biplane.obj");
}

#[test]
fn two_cylinder_engine_in_millimetres_builds_a_valid_bvh() {
    check_model("mesh/khronos_2cylinderengine.glb");
}

/// The dust pipeline runs through on both models in this debug build (the debug panics of issue
/// 18 were in the exposure scene's build).
#[test]
fn dust_runs_on_both_models_in_debug() {
    for rel in [
        "mesh/cartoon_biplane/cartoon_biplane.obj",
        "mesh/khronos_2cylinderengine.glb",
    ] {
        let mesh = decode(rel);
        let p = DustParams::from_json(
            &json!({"width": 96, "height": 64, "exposure_rays": 8}),
            &Limits::default(),
        )
        .unwrap();
        let outs = dust::run(&mesh, &p, &NoControl).unwrap();
        assert!(outs.iter().any(|o| o.name == "render.png"), "{rel}");
    }
}

/// The fallback tree stays within the traversal stack where a tree that follows the geometry
/// cannot: 3,000 nested triangles (each inside the next, as the biplane's thin shells are)
/// and 50,000 scattered ones. obvhs validates the trees (debug build).
#[test]
fn the_balanced_fallback_is_never_deeper_than_the_stack() {
    let nested: Vec<Triangle> = (0..3000)
        .map(|i| {
            let s = 1.002f32.powi(i);
            Triangle {
                v0: Vec3A::new(-s, 0.0, -s),
                v1: Vec3A::new(s, 0.0, -s),
                v2: Vec3A::new(0.0, 0.01 * s, s),
            }
        })
        .collect();
    let mut x = 12345u64;
    let mut rnd = || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        (x >> 40) as f32 / (1u64 << 24) as f32
    };
    let scattered: Vec<Triangle> = (0..50_000)
        .map(|_| {
            let c = Vec3A::new(rnd(), rnd(), rnd());
            Triangle {
                v0: c,
                v1: c + Vec3A::new(0.01 * rnd(), 0.0, 0.0),
                v2: c + Vec3A::new(0.0, 0.01 * rnd(), 0.01),
            }
        })
        .collect();
    for tris in [&nested, &scattered] {
        let bvh2 = balanced_bvh2(tris);
        assert!(bvh2.depth(0) <= CWBVH_STACK, "{}", bvh2.depth(0));
        bvh2.validate(tris, false, false);
        let cw = bvh2_to_cwbvh(&bvh2, 3, true, false);
        cw.validate(tris, false);
        assert!(cwbvh_depth(&cw) < CWBVH_STACK);
        // Every triangle is found by a ray straight down through its centroid.
        let scene_hits = tris.iter().step_by(97).all(|t| {
            let c = (t.v0 + t.v1 + t.v2) / 3.0;
            let ray = Ray::new_inf(c + Vec3A::new(0.0, 5.0, 0.0), Vec3A::new(0.0, -1.0, 0.0));
            !cw.ray_traverse_miss(ray, |r, id| {
                tris[cw.primitive_indices[id] as usize].intersect(r)
            })
        });
        assert!(scene_hits);
    }
}
