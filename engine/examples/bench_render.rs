//! Runs the code of `meshwiki bench render` (`src/cli/bench_render.rs`) from the engine:
//! `cargo run --release -p meshwiki-engine --example bench_render MODEL [OUT_DIR]` in the
//! repository root, where MODEL is a `.mwlod` file, a mesh file or `synth:N`.

#[path = "../../src/cli/bench_render.rs"]
mod bench_render;

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args_os().skip(1);
    let Some(model) = args.next() else {
        anyhow::bail!("usage: bench_render MODEL [OUT_DIR]  (MODEL: .mwlod, mesh file or synth:N)");
    };
    let out = args.next().map(std::path::PathBuf::from);
    bench_render::run(std::path::Path::new(&model), out.as_deref())
}
