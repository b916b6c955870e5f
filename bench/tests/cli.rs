//! The bench binary runs and prints its figures (a small `search`), and fails with a message
//! where its data is missing.

use std::process::Command;

#[test]
fn bench_search_prints_figures() {
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_meshwiki-bench"))
        .args(["search", "--docs", "2000", "--queries", "50", "--data-dir"])
        .arg(dir.path())
        .env("MESHWIKI_LOG", "warn")
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("index build:"), "{stdout}");
    assert!(stdout.contains("p50") && stdout.contains("p99"), "{stdout}");
    // The scratch directory is removed.
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
}

#[test]
fn select_without_the_benchmark_data_fails_with_a_message() {
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_meshwiki-bench"))
        .args(["select", "--psb"])
        .arg(dir.path().join("absent"))
        .env("MESHWIKI_LOG", "warn")
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("error:"), "{stderr}");
}
