//! Timing driver for the mesh readers (BENCHMARKS.md, snow cover session 21):
//! `mesh_decode FILE [REPS] [tobj]`. Decodes FILE REPS times (default 3) with `decode_mesh` and
//! prints each run's wall time; with `tobj`, an OBJ goes through the `tobj` path alone (the
//! reference of the parallel reader), and the two meshes are compared.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::print_stdout)]

use std::time::Instant;

use phenomena_engine::formats::mesh::{decode_mesh, decode_obj_tobj, MeshOptions};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let path = args.get(1).expect("mesh_decode FILE [REPS] [tobj]");
    let reps: usize = args.get(2).map_or(3, |r| r.parse().expect("REPS"));
    let reference = args.get(3).is_some_and(|a| a == "tobj");
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{path}: {e}"));
    let opts = MeshOptions::default();
    let mut last = None;
    for _ in 0..reps {
        let t = Instant::now();
        let mesh = if reference {
            decode_obj_tobj(&bytes, &opts)
        } else {
            decode_mesh(&bytes, Some(path), &opts)
        }
        .expect("decodes");
        println!(
            "{} {:.1} ms ({} vertices, {} triangles)",
            if reference { "tobj" } else { "decode_mesh" },
            t.elapsed().as_secs_f64() * 1e3,
            mesh.positions.len(),
            mesh.triangles.len()
        );
        last = Some(mesh);
    }
    if reference {
        let fast = decode_mesh(&bytes, Some(path), &opts).expect("decodes");
        println!("same mesh: {}", Some(&fast) == last.as_ref());
    }
}
