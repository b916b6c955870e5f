//! Runs the code of `meshwiki bench maxflow` (`src/cli/bench_maxflow.rs`) from the engine:
//! `cargo run --release -p meshwiki-engine --example bench_maxflow [DIR]` in the repository
//! root (DIR defaults to `../shared/data/maxflow`).

#[path = "../../src/cli/bench_maxflow.rs"]
mod bench_maxflow;

fn main() -> anyhow::Result<()> {
    let dir = std::env::args_os().nth(1).map(std::path::PathBuf::from);
    bench_maxflow::run(dir.as_deref())
}
