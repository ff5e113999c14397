//! BENCHMARKS.md is what `cargo run --example benchmarks_md` makes of benches/results/*.json.

#[path = "../benches/support/benchmarks_md.rs"]
mod benchmarks_md;

#[test]
fn benchmarks_md_matches_the_results() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let generated = benchmarks_md::render(root).expect("render BENCHMARKS.md");
    let committed = std::fs::read_to_string(root.join("BENCHMARKS.md")).expect("BENCHMARKS.md");
    assert!(
        generated == committed,
        "BENCHMARKS.md differs from benches/results/*.json: run `{}` and commit the result",
        benchmarks_md::COMMAND
    );
}
