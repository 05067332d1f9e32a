//! Helpers shared by the integration tests.
#![allow(dead_code)]

use candle_core::{Device, Tensor};
use candle_nn::{VarBuilder, VarMap};

pub fn cpu() -> Device {
    Device::Cpu
}

/// A seeded builder on a fresh map.
pub fn seeded(seed: u64) -> (VarMap, VarBuilder<'static>) {
    let vm = VarMap::new();
    let vb = nets::seeded_var_builder(&vm, seed, &cpu());
    (vm, vb)
}

pub fn t2(rows: &[&[f32]]) -> Tensor {
    let data: Vec<f32> = rows.iter().flat_map(|r| r.iter().copied()).collect();
    Tensor::from_vec(data, (rows.len(), rows[0].len()), &cpu()).unwrap()
}

pub fn t1(values: &[f32]) -> Tensor {
    Tensor::from_slice(values, values.len(), &cpu()).unwrap()
}

pub fn set(vm: &mut VarMap, name: &str, value: Tensor) {
    vm.set_one(name, value).unwrap();
}

pub fn vec2(t: &Tensor) -> Vec<Vec<f32>> {
    t.to_vec2::<f32>().unwrap()
}

pub fn flat(t: &Tensor) -> Vec<f32> {
    t.flatten_all().unwrap().to_vec1::<f32>().unwrap()
}

pub fn assert_close(got: &[f32], want: &[f64], tol: f64) {
    assert_eq!(got.len(), want.len(), "length: got {got:?}, want {want:?}");
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        let err = (f64::from(*g) - w).abs();
        assert!(
            err <= tol * (1.0 + w.abs()),
            "element {i}: got {g}, want {w} (|err| {err})"
        );
    }
}

pub fn max_abs_diff(a: &Tensor, b: &Tensor) -> f32 {
    assert_eq!(a.dims(), b.dims());
    flat(a)
        .iter()
        .zip(flat(b))
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

/// A random batch `[batch, dim]` in [-1, 1).
pub fn batch(batch: usize, dim: usize) -> Tensor {
    Tensor::rand(-1f32, 1.0, (batch, dim), &cpu()).unwrap()
}

/// Every variable of `vm` as (name, bit patterns), sorted by name: equal exactly when the
/// weights are bit-identical.
pub fn var_bits(vm: &VarMap) -> Vec<(String, Vec<u32>)> {
    let mut out: Vec<(String, Vec<u32>)> = vm
        .data()
        .lock()
        .unwrap()
        .iter()
        .map(|(n, v)| {
            (
                n.clone(),
                flat(v.as_tensor()).iter().map(|x| x.to_bits()).collect(),
            )
        })
        .collect();
    out.sort();
    out
}
