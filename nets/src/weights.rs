//! Parameter sets as bytes: safetensors serialisation of a [`VarMap`], strict loading, the
//! layout hash that receivers check, and subsets (e.g. only the actor-side networks).
//!
//! Layout hash: [`protocol::layout_hash`] over every tensor's name and shape (one definition
//! for every sender and receiver). It covers names and shapes, not dtypes or values.
//!
//! Invariants:
//! - Serialisation is deterministic: tensors sorted by name, no metadata; values bit-exact.
//! - Loading is all-or-nothing: every name, dtype and shape is checked before any value is
//!   written, so a rejected payload leaves the receiving set untouched.

use std::collections::HashMap;
use std::sync::MutexGuard;

use candle_core::safetensors::Load;
use candle_core::{DType, Tensor, Var};
use candle_nn::VarMap;
use safetensors::SafeTensors;

use crate::error::{NetsError, Result};

/// The layout hash of `(name, dims)` entries (any order), per the contract in the module doc.
pub fn layout_hash_of<'a, I>(entries: I) -> u64
where
    I: IntoIterator<Item = (&'a str, &'a [usize])>,
{
    protocol::layout_hash(entries)
}

/// The layout hash of every parameter in `varmap`.
pub fn layout_hash(varmap: &VarMap) -> u64 {
    let data = lock(varmap);
    layout_hash_of(data.iter().map(|(name, var)| (name.as_str(), var.dims())))
}

/// Serialises every parameter of `varmap` to safetensors bytes (sorted names, no metadata).
pub fn to_safetensors_bytes(varmap: &VarMap) -> Result<Vec<u8>> {
    let mut tensors: Vec<(String, Tensor)> = lock(varmap)
        .iter()
        .map(|(name, var)| (name.clone(), var.as_tensor().clone()))
        .collect();
    tensors.sort_by(|a, b| a.0.cmp(&b.0));
    Ok(safetensors::serialize(tensors, None)?)
}

/// Writes the values in `bytes` into the existing parameters of `varmap`.
///
/// The payload must hold exactly the names of `varmap`, each with the same dtype and shape;
/// otherwise nothing is written and the error names the first offending tensor (sorted order).
pub fn load_safetensors_bytes(varmap: &VarMap, bytes: &[u8]) -> Result<()> {
    let payload = SafeTensors::deserialize(bytes)?;
    let data = lock(varmap);
    let mut names: Vec<&String> = data.keys().collect();
    names.sort_unstable();
    let mut values = Vec::with_capacity(names.len());
    for name in names {
        let var = &data[name];
        values.push((var, checked_value(&payload, name, var)?));
    }
    check_no_extra(&payload, &data)?;
    for (var, value) in values {
        var.set(&value)?;
    }
    Ok(())
}

/// The payload's tensor for `name`, checked against `var`'s dtype and shape.
fn checked_value(payload: &SafeTensors, name: &str, var: &Var) -> Result<Tensor> {
    let view = payload.tensor(name).map_err(|_| NetsError::MissingTensor {
        name: name.to_string(),
        expected: var.dims().to_vec(),
    })?;
    let got_dtype = DType::try_from(view.dtype()).map_err(|_| NetsError::DType {
        name: name.to_string(),
        expected: format!("{:?}", var.dtype()),
        got: format!("{:?}", view.dtype()),
    })?;
    if got_dtype != var.dtype() {
        return Err(NetsError::DType {
            name: name.to_string(),
            expected: format!("{:?}", var.dtype()),
            got: format!("{got_dtype:?}"),
        });
    }
    if view.shape() != var.dims() {
        return Err(NetsError::ShapeMismatch {
            name: name.to_string(),
            expected: var.dims().to_vec(),
            got: view.shape().to_vec(),
        });
    }
    Ok(view.load(var.device())?)
}

/// Fails on the first (sorted) payload tensor that the receiving set lacks.
fn check_no_extra(payload: &SafeTensors, data: &HashMap<String, Var>) -> Result<()> {
    let mut names = payload.names();
    names.sort_unstable();
    match names.into_iter().find(|n| !data.contains_key(*n)) {
        None => Ok(()),
        Some(name) => Err(NetsError::UnexpectedTensor {
            name: name.to_string(),
            shape: payload
                .tensor(name)
                .map(|v| v.shape().to_vec())
                .unwrap_or_default(),
        }),
    }
}

/// Whether `name` lies under `prefix` (equal to it, or starting with `prefix.`).
pub fn is_under(name: &str, prefix: &str) -> bool {
    name.strip_prefix(prefix)
        .is_some_and(|rest| rest.is_empty() || rest.starts_with('.'))
}

/// A `VarMap` holding the parameters of `varmap` under any of `prefixes`, sharing their
/// storage (a write through one is seen by the other). Use it to publish part of a set, e.g.
/// `subset(&vm, &prefix::ACTOR_SIDE)` or only φ for the graph-service. Names are unchanged.
/// A prefix that matches nothing is an error ([`NetsError::Spec`]), so a typo cannot publish
/// an empty set.
pub fn subset(varmap: &VarMap, prefixes: &[&str]) -> Result<VarMap> {
    let data = lock(varmap);
    if let Some(p) = prefixes
        .iter()
        .find(|p| !data.keys().any(|n| is_under(n, p)))
    {
        return Err(NetsError::Spec(format!(
            "subset: no parameter under prefix `{p}`"
        )));
    }
    let out = VarMap::new();
    {
        let mut out_data = lock(&out);
        for (name, var) in data
            .iter()
            .filter(|(n, _)| prefixes.iter().any(|p| is_under(n, p)))
        {
            out_data.insert(name.clone(), var.clone());
        }
    }
    Ok(out)
}

/// The parameters under `prefix`, sorted by name (e.g. to give one network its optimiser).
pub fn vars_under(varmap: &VarMap, prefix: &str) -> Vec<Var> {
    let data = lock(varmap);
    let mut named: Vec<(&String, &Var)> =
        data.iter().filter(|(n, _)| is_under(n, prefix)).collect();
    named.sort_unstable_by(|a, b| a.0.cmp(b.0));
    named.into_iter().map(|(_, v)| v.clone()).collect()
}

/// Locks the map. A poisoned lock is recovered: the map of `Var` handles is never left
/// half-updated by a panic (each insert is a single operation), so its contents stay valid.
fn lock(varmap: &VarMap) -> MutexGuard<'_, HashMap<String, Var>> {
    varmap
        .data()
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
}
