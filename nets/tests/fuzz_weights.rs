//! Bounded fuzzing of the weights decoder (issue #7, "hostile input"): mutated and truncated
//! safetensors payloads are either loaded completely or refused with nothing written — a failed
//! load never leaves a half-updated network — and never panic.
//!
//! Cases: `FUZZ_CASES` (default 2,000), from a fixed-seed generator so a failure reproduces.

mod common;

use candle_nn::VarMap;
use common::*;
use nets::{load_safetensors_bytes, to_safetensors_bytes, NetsSpec, PolicySet};

/// A small policy set (tiny hidden layers keep each case cheap; the format is the same).
fn small_set(seed: u64) -> VarMap {
    let spec = NetsSpec {
        encoder_hidden: vec![4],
        high_hidden: vec![4],
        low_hidden: vec![4],
        low_critic_hidden: vec![4],
        ..NetsSpec::default()
    };
    let (vm, vb) = seeded(seed);
    PolicySet::new(&spec, &vb).unwrap();
    vm
}

/// SplitMix64: a tiny fixed-seed generator for the mutations.
struct SplitMix(u64);

impl SplitMix {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
}

#[test]
fn mutated_weight_payloads_load_completely_or_not_at_all() {
    let cases: usize = std::env::var("FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(2_000);
    let source = to_safetensors_bytes(&small_set(1)).unwrap();
    let target = small_set(2);
    let mut rng = SplitMix(0x5eed);
    let (mut loaded, mut refused) = (0, 0);
    for case in 0..cases {
        let mut bytes = source.clone();
        // Mostly mutate the JSON header (first ~1 KB, where the structure is), sometimes the data.
        let header_len = 8 + u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
        for _ in 0..1 + rng.below(4) {
            let at = if rng.below(4) == 0 {
                rng.below(bytes.len())
            } else {
                rng.below(header_len)
            };
            bytes[at] = rng.next() as u8;
        }
        if rng.below(5) == 0 {
            let keep = rng.below(bytes.len() + 1);
            bytes.truncate(keep);
        }
        let before = var_bits(&target);
        match load_safetensors_bytes(&target, &bytes) {
            Ok(()) => {
                loaded += 1;
                // A successful load writes every tensor of the payload: reload the same bytes
                // into a fresh set and compare.
                let fresh = small_set(3);
                load_safetensors_bytes(&fresh, &bytes).unwrap();
                assert_eq!(
                    var_bits(&target),
                    var_bits(&fresh),
                    "case {case}: partial load"
                );
            }
            Err(err) => {
                refused += 1;
                assert!(!err.to_string().is_empty());
                assert_eq!(
                    var_bits(&target),
                    before,
                    "case {case}: refused load changed weights ({err})"
                );
            }
        }
    }
    // Both outcomes must be exercised, or the fuzzer tests nothing.
    assert!(
        loaded > 0 && refused > 0,
        "loaded {loaded}, refused {refused}"
    );
}
