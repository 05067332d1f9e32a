//! Throughput of the checkpoint file checksum (CRC-64/XZ, slicing-by-16) against the word-wise
//! FNV-1a fingerprint it replaced in manifest format 2, over one buffer of checkpoint size.
//!
//! Run: `cargo run --release -p ckpt --example bench_checksum [-- MIB]` (default 256 MiB; five
//! passes of each, the median printed in GiB/s).

use std::time::Instant;

fn median_gib_per_s(bytes: &[u8], f: fn(&[u8]) -> u64) -> (f64, u64) {
    let mut rates = Vec::new();
    let mut value = 0;
    for _ in 0..5 {
        let start = Instant::now();
        value = std::hint::black_box(f(std::hint::black_box(bytes)));
        let secs = start.elapsed().as_secs_f64();
        rates.push(bytes.len() as f64 / secs / (1u64 << 30) as f64);
    }
    rates.sort_by(f64::total_cmp);
    (rates[2], value)
}

fn main() {
    let mib: usize = match std::env::args().nth(1) {
        None => 256,
        Some(arg) => arg.parse().unwrap_or_else(|_| {
            eprintln!("usage: bench_checksum [MIB] (a whole number of MiB, got '{arg}')");
            std::process::exit(2)
        }),
    };
    // Not all zeros or one repeated byte: a fixed pseudo-random fill.
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let bytes: Vec<u8> = (0..mib << 20)
        .map(|_| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state as u8
        })
        .collect();
    println!("{mib} MiB, median of 5 passes");
    for (name, f) in [
        ("checksum (CRC-64/XZ)", ckpt::checksum as fn(&[u8]) -> u64),
        ("fingerprint (FNV-1a words)", ckpt::fingerprint),
    ] {
        let (rate, value) = median_gib_per_s(&bytes, f);
        println!("{name:28} {rate:6.2} GiB/s  ({value:016x})");
    }
}
