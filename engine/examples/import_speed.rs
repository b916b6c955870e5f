//! Measures import throughput: `cargo run -p meshwiki-engine --example import_speed FILE...`
//! (a sink that only counts, so the figure is the reader's own speed).

use meshwiki_engine::mesh::{self, ImportError, MeshSink, SourceInfo, VertexBatch};
use meshwiki_engine::progress::NoProgress;
use std::time::Instant;

struct Count(u64, u64);

impl MeshSink for Count {
    fn begin(&mut self, _: &SourceInfo) -> Result<(), ImportError> {
        Ok(())
    }
    fn vertices(&mut self, b: VertexBatch<'_>) -> Result<(), ImportError> {
        self.0 += b.positions.len() as u64;
        Ok(())
    }
    fn triangles(&mut self, t: &[[u32; 3]]) -> Result<(), ImportError> {
        self.1 += t.len() as u64;
        Ok(())
    }
}

fn main() {
    for arg in std::env::args().skip(1) {
        // `synth:N:FILE` writes the demo relief of N triangles first.
        let arg = match arg.strip_prefix("synth:").and_then(|r| r.split_once(':')) {
            Some((n, file)) => {
                let t = Instant::now();
                let (v, tris) =
                    mesh::write_relief_ply(std::path::Path::new(file), n.parse().unwrap_or(1000))
                        .unwrap_or_else(|e| panic!("{e}"));
                println!(
                    "synth {file}: {v} vertices, {tris} triangles in {:.2} s",
                    t.elapsed().as_secs_f64()
                );
                file.to_string()
            }
            None => arg,
        };
        let path = std::path::Path::new(&arg);
        let bytes = std::fs::metadata(path).map(|m| m.len()).unwrap_or(0);
        for run in 0..3 {
            let mut sink = Count(0, 0);
            let t = Instant::now();
            match mesh::import(path, &mut sink, &NoProgress) {
                Ok(s) => {
                    let secs = t.elapsed().as_secs_f64();
                    println!(
                        "{arg} run {run}: {} vertices, {} triangles in {secs:.3} s: {:.0} MB/s, {:.1} M triangles/s",
                        s.vertices,
                        s.triangles,
                        bytes as f64 / secs / 1e6,
                        s.triangles as f64 / secs / 1e6
                    );
                }
                Err(e) => {
                    eprintln!("{e}");
                    std::process::exit(1);
                }
            }
        }
    }
}
