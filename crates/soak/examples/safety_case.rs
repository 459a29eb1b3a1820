//! One case of the safety soak, run again and described, for investigating a violation:
//! `cargo run -p gonio-soak --example safety_case -- SEED INDEX [FROM_S TO_S]`
//! (the case, its verdict, and the arms' motion commands and profile changes in that window of simulated time).

fn main() {
    let args: Vec<f64> = std::env::args().skip(1).filter_map(|a| a.parse().ok()).collect();
    let (seed, index) = match args.as_slice() {
        [s, i, ..] => (*s as u64, *i as u32),
        _ => {
            eprintln!("usage: safety_case SEED INDEX [FROM_S TO_S]");
            std::process::exit(2);
        }
    };
    let from_s = args.get(2).copied().unwrap_or(0.0);
    let to_s = args.get(3).copied().unwrap_or(f64::INFINITY);
    match gonio_soak::safety_soak::trace(seed, index, from_s, to_s) {
        Ok(text) => print!("{text}"),
        Err(e) => {
            eprintln!("safety_case: {e}");
            std::process::exit(2);
        }
    }
}
