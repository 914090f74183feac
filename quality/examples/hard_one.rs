//! Runs named hard cases: `cargo run -p lightfold-quality --example hard_one -- [--full] NAME...`.
fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let full = args.iter().any(|a| a == "--full");
    for name in args.iter().filter(|a| !a.starts_with("--")) {
        let t = std::time::Instant::now();
        let r = lightfold_quality::hard::run_case(name, full)?;
        println!("{r}\n  ({:.1} s)", t.elapsed().as_secs_f64());
    }
    Ok(())
}
