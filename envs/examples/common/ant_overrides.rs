//! `key=value` overrides of [`AntParams`] for the tuning examples (`fidelity`,
//! `bench_ant_variants`), shared through `#[path]` so both accept the same keys.

use envs::ant::AntParams;
use envs::EnvError;

/// Sets one tunable parameter from text; an unknown key or unparsable value is an error.
pub fn apply_override(params: &mut AntParams, key: &str, value: &str) -> Result<(), EnvError> {
    let float = || value.parse::<f32>().map_err(|_| bad_arg(key, value));
    let count = || value.parse::<usize>().map_err(|_| bad_arg(key, value));
    let solver = &mut params.solver;
    match key {
        "timestep_secs" => params.timestep_secs = float()?,
        "frame_skip" => params.frame_skip = count()? as u32,
        "friction" => params.friction = float()?,
        "solver.substeps" => solver.substeps = count()?,
        "solver.pgs_iterations" => solver.pgs_iterations = count()?,
        "solver.stabilization_iterations" => solver.stabilization_iterations = count()?,
        "solver.contact_frequency_hz" => solver.contact_frequency_hz = float()?,
        "solver.contact_damping_ratio" => solver.contact_damping_ratio = float()?,
        "solver.contact_skin_m" => solver.contact_skin_m = float()?,
        "solver.joint_limit_frequency_hz" => solver.joint_limit_frequency_hz = float()?,
        "solver.joint_limit_damping_ratio" => solver.joint_limit_damping_ratio = float()?,
        "solver.max_corrective_velocity_m_s" => solver.max_corrective_velocity_m_s = float()?,
        "solver.ccd_max_substeps" => solver.ccd_max_substeps = count()?,
        "solver.broad_phase_optimization" => {
            solver.broad_phase_optimization = value.parse().map_err(|_| bad_arg(key, value))?
        }
        _ => return Err(bad_arg(key, value)),
    }
    Ok(())
}

/// The error for an argument the examples do not understand.
pub fn bad_arg(key: &str, value: &str) -> EnvError {
    EnvError::InvalidParam {
        field: key.to_string(),
        value: value.to_string(),
        reason: "unknown argument or unparsable value (see envs/examples/common/ant_overrides.rs)"
            .into(),
    }
}
