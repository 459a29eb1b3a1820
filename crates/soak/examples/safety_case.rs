//! One case of the safety soak, run again and described, for investigating a violation:
//! `cargo run -p gonio-soak --example safety_case -- SEED INDEX [FROM_S TO_S]`
//! (the case, its verdict, and the arms' motion commands and profile changes in that window of simulated time).

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    // The seed is parsed as an integer: any u64 (the property test draws them at random) names its case exactly.
    let parsed = match args.as_slice() {
        [s, i, rest @ ..] => s.parse::<u64>().ok().zip(i.parse::<u32>().ok()).map(|(s, i)| {
            let window: Vec<f64> = rest.iter().filter_map(|a| a.parse().ok()).collect();
            (s, i, window)
        }),
        _ => None,
    };
    let Some((seed, index, window)) = parsed else {
        eprintln!("usage: safety_case SEED INDEX [FROM_S TO_S]");
        std::process::exit(2);
    };
    let from_s = window.first().copied().unwrap_or(0.0);
    let to_s = window.get(1).copied().unwrap_or(f64::INFINITY);
    match gonio_soak::safety_soak::trace(seed, index, from_s, to_s) {
        Ok(text) => print!("{text}"),
        Err(e) => {
            eprintln!("safety_case: {e}");
            std::process::exit(2);
        }
    }
}
